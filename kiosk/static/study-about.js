// The optional questions, one form for both study pages: the kiosk's (study.js) and the self-contained web page
// (webpage.js; `vtkiosk study export-page` inlines this file). "Prefer not to say" comes first and sends nothing.
"use strict";

function fillAboutForm(form, fields) {
  form.replaceChildren();
  for (const [name, choices] of Object.entries(fields)) {
    const label = document.createElement("label");
    label.textContent = name.replace(/_/g, " ");
    label.htmlFor = `about-${name}`;
    const select = document.createElement("select");
    select.id = `about-${name}`;
    select.name = name;
    select.add(new Option("prefer not to say", ""));
    for (const c of choices) select.add(new Option(c, c));
    form.append(label, select);
  }
}
