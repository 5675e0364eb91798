// The researcher's live view (loopback only): who is in the study, at which stage, which garment lies on the
// table, how much time is left. It changes nothing except releasing the waiting trial. Running preference counts
// are fetched only while the switch is on.
"use strict";

const $ = (id) => document.getElementById(id);
const STAGES = { consent: "reading the consent text", demographics: "answering the optional questions",
  familiarisation: "feeling the familiarisation textures", wait: "waiting for you to release the next trial",
  trial: "exploring a trial", timeout: "being told the time ran out" };

async function refresh() {
  let st;
  try {
    const res = await fetch(`/api/study/operator?counts=${$("show-counts").checked ? 1 : 0}`);
    st = await res.json();
    if (!res.ok) throw new Error(st.error || `HTTP ${res.status}`);
  } catch (err) {
    $("problem").textContent = `the study is not answering (${err.message})`;
    return;
  }
  $("study").textContent = st.study_id;
  $("kind").textContent = `(${st.kind} study)`;
  const a = st.active;
  $("who").textContent = a ? `${a.participant}, session ${a.session}` : "no session running";
  $("stage").textContent = a ? STAGES[a.stage] || a.stage : (st.finished ? `last: ${st.finished.participant} finished` : "");
  $("progress").textContent = a ? `${a.test_answered} of ${a.test_trials} test trials answered` +
    (a.familiarisation ? `; texture ${a.familiarisation.step} of ${a.familiarisation.of}: ${a.familiarisation.texture}` : "") : "";
  $("time").textContent = a && a.time_left_s !== null ? `${Math.ceil(a.time_left_s)} s left` : "";
  $("problem").textContent = a && a.error ? a.error : "";
  $("garment").textContent = a && a.put_garment_on_table ? a.put_garment_on_table : "-";
  $("release").disabled = !(a && a.waiting_for_release);
  const table = $("counts");
  table.hidden = !st.counts;
  const body = table.querySelector("tbody");
  body.replaceChildren();
  for (const c of st.counts || []) {
    const row = body.insertRow();
    for (const v of [`${c.reference} vs ${c.comparison}`, c.prefer_reference, c.n, c.timeouts]) row.insertCell().textContent = v;
  }
  $("summary").textContent = `${st.sessions} session(s), ${st.responses} response(s) logged` +
    (st.withdrawn.length ? `; withdrawn: ${st.withdrawn.join(", ")}` : "");
}

$("release").addEventListener("click", async () => {
  $("release").disabled = true;
  const res = await fetch("/api/study/operator/next", { method: "POST", headers: { "Content-Type": "application/json" }, body: "{}" });
  const data = await res.json().catch(() => ({}));
  if (!data.ok) $("problem").textContent = data.error || "the release was refused";
  refresh();
});
$("show-counts").addEventListener("change", refresh);
setInterval(refresh, 1000);
refresh();
