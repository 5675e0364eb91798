// The study page. Haptic study: both halves show the same ground-truth visual and the haptic screen renders a
// different friction map under each; visual study: each half shows one method's visual output. The participant
// taps "left" or "right". The daemon is authoritative about time and stages: this page only shows what
// /api/study/trial says, tells the daemon when a trial is on screen (/api/study/shown, with this page's id so a
// reloaded page restarts the response time), and sends answers with the stage's token. Between trials the page
// says "please wait" until the experimenter releases the next trial (the N key on the kiosk's keyboard, the
// operator page, or `vtkiosk study next`).
"use strict";

const $ = (id) => document.getElementById(id);
const stage = $("stage");
const ctx = stage.getContext("2d");
const band = $("band");
const question = $("question");
const instructionsLine = $("instructions-line");
const clock = $("clock");
const progress = $("progress");
const buttons = { left: $("choose-left"), right: $("choose-right") };
const nextTexture = $("next-texture");
const screens = { notice: $("notice"), consent: $("consent"), about: $("about") };

const pageId = (crypto.randomUUID ? crypto.randomUUID() :
  Array.from({ length: 4 }, () => Math.random().toString(16).slice(2, 10)).join("")).slice(0, 64);
let view = null;         // the state on screen: {state, token, ...}
let deadline = null;     // performance.now() ms when the daemon's time limit ends (timed trials)
let busy = false;        // an answer is in flight
const images = new Map();

async function api(method, path, body) {
  const opts = { method, headers: {} };
  if (body !== undefined) {
    opts.headers["Content-Type"] = "application/json";
    opts.body = JSON.stringify(body);
  }
  const res = await fetch(path, opts);
  const data = await res.json().catch(() => ({}));
  if (!res.ok) throw new Error(data.error || `${method} ${path}: HTTP ${res.status}`);
  return data;
}

function loadImage(url) {
  if (images.has(url)) return images.get(url);
  const p = new Promise((resolve, reject) => {
    const img = new Image();
    img.onload = () => resolve(img);
    img.onerror = () => reject(new Error(`cannot load ${url}`));
    img.src = url;
  });
  images.set(url, p);
  if (images.size > 64) images.delete(images.keys().next().value);
  return p;
}

// The colour along an image's border: a panel is filled with it, so the part of a panel the image does not cover
// continues the image's own background instead of showing a band of another colour.
const borderColours = new WeakMap();
function borderColour(img) {
  if (borderColours.has(img)) return borderColours.get(img);
  const c = document.createElement("canvas");
  c.width = img.naturalWidth;
  c.height = img.naturalHeight;
  const g = c.getContext("2d", { willReadFrequently: true });
  g.drawImage(img, 0, 0);
  const { data } = g.getImageData(0, 0, c.width, c.height);
  let r = 0, gr = 0, b = 0, n = 0;
  const add = (x, y) => {
    const i = 4 * (y * c.width + x);
    if (data[i + 3] < 128) return;   // transparent (outside the object): not the background we see
    r += data[i]; gr += data[i + 1]; b += data[i + 2]; n += 1;
  };
  for (let x = 0; x < c.width; x++) { add(x, 0); add(x, c.height - 1); }
  for (let y = 0; y < c.height; y++) { add(0, y); add(c.width - 1, y); }
  const colour = n ? `rgb(${Math.round(r / n)},${Math.round(gr / n)},${Math.round(b / n)})` : "#111";
  borderColours.set(img, colour);
  return colour;
}

function showScreen(name) {
  for (const [k, el] of Object.entries(screens)) el.hidden = k !== name;
  const onStage = name === null;
  band.hidden = !onStage;
  for (const b of Object.values(buttons)) {
    b.hidden = !onStage || (view && view.state !== "trial");
    if (!onStage) b.disabled = true;
  }
  nextTexture.hidden = !(onStage && view && view.state === "familiarisation");
  if (!onStage) clock.textContent = "";
}

function showNotice(text, instructions) {
  $("notice-text").textContent = text;
  const p = $("notice-instructions");
  p.textContent = instructions || "";
  p.hidden = !instructions;
  showScreen("notice");
}

// Screen pixels (the haptic panel's coordinates) -> CSS pixels of this page.
function fit(screen) {
  const w = window.innerWidth, h = window.innerHeight;
  return { k: Math.min(w / screen[0], h / screen[1]), w, h };
}

function place(el, rect, k) {
  const [x, y, w, h] = rect;
  Object.assign(el.style, { left: `${x * k}px`, top: `${y * k}px`, width: `${w * k}px`, height: `${h * k}px` });
}

function prepareCanvas(screen) {
  const { k, w, h } = fit(screen);
  const dpr = window.devicePixelRatio || 1;
  stage.width = Math.round(w * dpr);
  stage.height = Math.round(h * dpr);
  ctx.setTransform(dpr * k, 0, 0, dpr * k, 0, 0);
  ctx.fillStyle = "#111";
  ctx.fillRect(0, 0, screen[0], screen[1]);
  return k;
}

function layoutBand(rect, k) {
  place(band, rect, k);
  band.style.fontSize = `${Math.max(12, Math.min(24, rect[3] * k * 0.32))}px`;
}

async function drawTrial(trial) {
  const k = prepareCanvas(trial.screen);
  layoutBand(trial.question_rect, k);
  for (const p of trial.panels) {
    const img = await loadImage(trial.kind === "visual" ? p.image : trial.visual);
    const [x, y, pw, ph] = p.rect;
    ctx.save();
    ctx.beginPath();
    ctx.rect(x, y, pw, ph);
    ctx.clip();
    ctx.fillStyle = borderColour(img);
    ctx.fillRect(x, y, pw, ph);
    ctx.imageSmoothingQuality = "high";
    const pl = p.placement;
    if (pl.rect) ctx.drawImage(img, pl.rect[0], pl.rect[1], pl.rect[2], pl.rect[3]);
    else ctx.drawImage(img, pl.x, pl.y, pl.size[0] * pl.scale, pl.size[1] * pl.scale);
    ctx.restore();
  }
  for (const b of trial.buttons) {
    place(buttons[b.side], b.rect, k);
    buttons[b.side].classList.remove("chosen");
  }
}

async function presentTrial(state) {
  const trial = state.trial;
  view = { state: "trial", token: trial.token, trial };
  deadline = null;
  question.textContent = trial.question;
  instructionsLine.textContent = trial.instructions || "";
  progress.textContent = trial.block === "warmup" ? "practice" : `${trial.number} / ${trial.of}`;
  await drawTrial(trial);
  showScreen(null);
  const shown = await api("POST", "/api/study/shown", { token: trial.token, page: pageId });
  if (shown.time_left_s !== null && shown.time_left_s !== undefined) {
    deadline = performance.now() + 1000 * shown.time_left_s;
  }
  busy = false;
  for (const b of Object.values(buttons)) b.disabled = false;
}

async function presentTexture(state) {
  view = { state: "familiarisation", token: state.token };
  const k = prepareCanvas(state.screen);
  layoutBand([0, 0, state.screen[0], state.rect[1]], k);
  question.textContent = `Texture ${state.step} of ${state.of}: ${state.label}`;
  instructionsLine.textContent = "Slide your finger over the screen to feel it, then tap \"next texture\".";
  progress.textContent = "getting to know the screen";
  const img = await loadImage(state.image);
  const [x, y, w, h] = state.rect;
  ctx.drawImage(img, x, y, w, h);
  const bar = [Math.round(state.screen[0] * 0.3), y + h + 8, Math.round(state.screen[0] * 0.4),
               state.screen[1] - y - h - 16];
  place(nextTexture, bar, k);
  busy = false;
  nextTexture.disabled = false;
  showScreen(null);
}

function presentConsent(state) {
  view = { state: "consent", token: state.token, version: state.consent.version };
  $("consent-text").textContent = state.consent.text;
  $("consent-version").textContent = state.consent.version;
  busy = false;
  showScreen("consent");
}

function presentAbout(state) {
  view = { state: "demographics", token: state.token };
  fillAboutForm($("about-form"), state.fields);
  busy = false;
  showScreen("about");
}

async function send(path, body) {
  if (!view || busy) return;        // the daemon ignores (and logs) double taps too
  busy = true;
  try {
    const res = await api("POST", path, { token: view.token, ...body });
    if (res.recorded === false) console.info("answer ignored:", res.ignored);
  } catch (err) {
    console.warn(err.message);
  }
  view = null;
  await poll();
}

function choose(side) {
  if (!view || view.state !== "trial" || busy) return;
  for (const b of Object.values(buttons)) b.disabled = true;
  buttons[side].classList.add("chosen");
  send("/api/study/choice", { side });
}

async function poll() {
  let state;
  try {
    state = await api("GET", "/api/study/trial");
  } catch (err) {
    view = null;
    showNotice("The kiosk is not answering. Please wait for the experimenter.");
    return;
  }
  const token = state.state === "trial" ? state.trial.token : state.token;
  if (view && view.state === state.state && token && view.token === token) return;   // already on screen
  try {
    if (state.state === "trial") await presentTrial(state);
    else if (state.state === "familiarisation") await presentTexture(state);
    else if (state.state === "consent") presentConsent(state);
    else if (state.state === "demographics") presentAbout(state);
    else {
      view = { state: state.state };
      showNotice(state.notice || "Please wait for the experimenter.", state.instructions);
    }
  } catch (err) {
    console.warn(err.message);
    view = null;
  }
}

function tick() {
  if (view && view.state === "trial" && deadline !== null) {
    const left = Math.max(0, (deadline - performance.now()) / 1000);
    clock.textContent = `${Math.ceil(left)} s left`;
    if (left <= 0 && !busy) {
      for (const b of Object.values(buttons)) b.disabled = true;
      clock.textContent = "time is up";
    }
  } else if (view && view.state === "trial") {
    clock.textContent = "";
  }
}

for (const b of Object.values(buttons)) {
  b.addEventListener("pointerdown", (ev) => { ev.preventDefault(); choose(b.dataset.side); });
}
nextTexture.addEventListener("pointerdown", (ev) => {
  ev.preventDefault();
  if (view && view.state === "familiarisation" && !busy) { nextTexture.disabled = true; send("/api/study/familiarised", {}); }
});
$("consent-yes").addEventListener("click", () => send("/api/study/consent", { agreed: true, version: view && view.version }));
$("consent-no").addEventListener("click", () => send("/api/study/consent", { agreed: false, version: view && view.version }));
$("about-go").addEventListener("click", () => {
  const answers = {};
  for (const el of $("about-form").elements) answers[el.name] = el.value === "" ? null : el.value;
  send("/api/study/demographics", { answers });
});
// The experimenter's key on the kiosk's keyboard releases the waiting trial (participants only touch the screen).
window.addEventListener("keydown", (ev) => {
  if ((ev.key === "n" || ev.key === "N") && view && view.state === "wait") {
    api("POST", "/api/study/release", {}).then(poll).catch((err) => console.warn(err.message));
  }
});
window.addEventListener("resize", () => { if (view && view.state === "trial") drawTrial(view.trial); });
setInterval(() => { if (!busy) poll(); }, 500);
setInterval(tick, 100);
poll();
