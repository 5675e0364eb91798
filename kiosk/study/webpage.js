// A visual A/B study as a self-contained page. It writes the kiosk's study-log records (canonical JSON, sequence
// numbers, SHA-256 checksums: kiosk/study/log.py) into the browser's storage, so a reload resumes, and offers the
// log as a download at the end. Schedules, images and texts were made by `vtkiosk study export-page`.
"use strict";

const DATA = JSON.parse(document.getElementById("study-data").textContent);
const $ = (id) => document.getElementById(id);

// --- SHA-256 (FIPS 180-4) over the bytes of an ASCII string ----------------------------------------------------
const K = new Uint32Array(64);
const H0 = new Uint32Array(8);
(() => {
  const primes = [];
  for (let n = 2; primes.length < 64; n++) if (primes.every((p) => n % p)) primes.push(n);
  const frac = (x) => Math.floor((x - Math.floor(x)) * 4294967296) >>> 0;
  primes.forEach((p, i) => { K[i] = frac(Math.cbrt(p)); if (i < 8) H0[i] = frac(Math.sqrt(p)); });
})();

function sha256Hex(text) {
  const bytes = new Uint8Array(text.length);
  for (let i = 0; i < text.length; i++) bytes[i] = text.charCodeAt(i);
  const bitLen = bytes.length * 8;
  const padded = new Uint8Array(((bytes.length + 9 + 63) >> 6) << 6);
  padded.set(bytes);
  padded[bytes.length] = 0x80;
  const view = new DataView(padded.buffer);
  view.setUint32(padded.length - 8, Math.floor(bitLen / 4294967296));
  view.setUint32(padded.length - 4, bitLen >>> 0);
  const h = H0.slice();
  const w = new Uint32Array(64);
  const rotr = (x, n) => (x >>> n) | (x << (32 - n));
  for (let off = 0; off < padded.length; off += 64) {
    for (let t = 0; t < 16; t++) w[t] = view.getUint32(off + 4 * t);
    for (let t = 16; t < 64; t++) {
      const s0 = rotr(w[t - 15], 7) ^ rotr(w[t - 15], 18) ^ (w[t - 15] >>> 3);
      const s1 = rotr(w[t - 2], 17) ^ rotr(w[t - 2], 19) ^ (w[t - 2] >>> 10);
      w[t] = (w[t - 16] + s0 + w[t - 7] + s1) >>> 0;
    }
    let [a, b, c, d, e, f, g, hh] = h;
    for (let t = 0; t < 64; t++) {
      const t1 = (hh + (rotr(e, 6) ^ rotr(e, 11) ^ rotr(e, 25)) + ((e & f) ^ (~e & g)) + K[t] + w[t]) >>> 0;
      const t2 = ((rotr(a, 2) ^ rotr(a, 13) ^ rotr(a, 22)) + ((a & b) ^ (a & c) ^ (b & c))) >>> 0;
      hh = g; g = f; f = e; e = (d + t1) >>> 0; d = c; c = b; b = a; a = (t1 + t2) >>> 0;
    }
    [a, b, c, d, e, f, g, hh].forEach((v, i) => { h[i] = (h[i] + v) >>> 0; });
  }
  return Array.from(h, (v) => v.toString(16).padStart(8, "0")).join("");
}

// --- the log's canonical JSON (Python: sort_keys, no spaces, ensure_ascii) ---------------------------------------
function canon(v) {
  if (v === null || v === undefined) return "null";
  if (typeof v === "boolean") return v ? "true" : "false";
  if (typeof v === "number") {
    if (!Number.isFinite(v)) throw new Error("a record cannot hold a non-finite number");
    return String(v);
  }
  if (typeof v === "string") {
    return JSON.stringify(v).replace(/[\u007f-\uffff]/g, (ch) => "\\u" + ch.charCodeAt(0).toString(16).padStart(4, "0"));
  }
  if (Array.isArray(v)) return "[" + v.map(canon).join(",") + "]";
  return "{" + Object.keys(v).filter((k) => v[k] !== undefined).sort()
    .map((k) => canon(k) + ":" + canon(v[k])).join(",") + "}";
}

// Times: whole milliseconds as seconds, never below 1 ms when not zero (the number format then matches Python's).
const secs = (ms) => { const s = Math.round(ms) / 1000; return s === 0 ? 0 : Math.max(s, 0.001); };
const now = () => ({ wall: new Date().toISOString(), mono: secs(performance.now()), boot_id: bootId });
const bootId = "web-" + Array.from(crypto.getRandomValues(new Uint8Array(8)), (b) => b.toString(16).padStart(2, "0")).join("");

// --- the session's records --------------------------------------------------------------------------------------
let code = null;
let session = null;     // the embedded session payload (schedule, bundles, config hash)
let records = [];
let key = null;

function append(type, payload) {
  const rec = { seq: records.length + 1, type, ...payload };
  rec.sum = sha256Hex(canon(Object.fromEntries(Object.entries(rec).filter(([k]) => k !== "sum")))).slice(0, 16);
  records.push(rec);
  localStorage.setItem(key, JSON.stringify(records));
  if (DATA.post_url) {
    fetch(DATA.post_url, { method: "POST", headers: { "Content-Type": "application/x-ndjson" }, body: canon(rec) + "\n",
      keepalive: true }).catch(() => {});
  }
  return rec;
}

function begin(c) {
  code = c;
  session = DATA.sessions[c];
  key = `vtkiosk-study:${DATA.study_id}:${c}`;
  records = JSON.parse(localStorage.getItem(key) || "[]");
  if (!records.length) {
    append("log", { format: DATA.format, version: DATA.version, study_id: DATA.study_id, created: now().wall,
      software: DATA.software });
    append("session", { ...session, ...now() });
  } else {
    append("resume", { participant: code, session: 1, reason: "reload", at_trial: nextTrial(), ...now() });
  }
  advance();
}

const byType = (t) => records.filter((r) => r.type === t);
const trials = () => session.schedule.trials;
function nextTrial() {
  const done = new Set(byType("response").map((r) => r.trial));
  const t = trials().find((x) => !done.has(x.index));
  return t ? t.index : null;
}

// --- screens ----------------------------------------------------------------------------------------------------
const screens = ["code", "notice", "consent", "about"];
function show(name) {
  for (const s of screens) $(s).hidden = s !== name;
  const stageOn = name === null;
  $("band").hidden = !stageOn;
  for (const side of ["left", "right"]) $(`choose-${side}`).hidden = !stageOn;
  if (!stageOn) $("stage").getContext("2d").clearRect(0, 0, $("stage").width, $("stage").height);
}

function notice(text, opts = {}) {
  $("notice-text").textContent = text;
  $("notice-instructions").textContent = opts.instructions || "";
  $("notice-instructions").hidden = !opts.instructions;
  $("notice-actions").hidden = !opts.start;
  $("download-row").hidden = !opts.download;
  show("notice");
}

let current = null;   // {trial, shown, timer}
let instructed = false;

function advance() {
  current = null;
  const ended = byType("end").length > 0;
  const consent = byType("consent").slice(-1)[0];
  if (ended) {
    notice(consent && !consent.agreed ? "Thank you. The study does not go on without your consent."
      : "Thank you! You have finished. Please download your answers and send the file as instructed.",
      { download: true });
    return;
  }
  if (DATA.consent && !(consent && consent.agreed)) {
    $("consent-text").textContent = DATA.consent.text;
    $("consent-version").textContent = DATA.consent.version;
    show("consent");
    return;
  }
  if (DATA.demographics && !byType("demographics").length) {
    fillAboutForm($("about-form"), DATA.demographics);
    show("about");
    return;
  }
  const index = nextTrial();
  if (index === null) {
    append("end", { participant: code, session: 1, reason: "complete", ...now() });
    advance();
    return;
  }
  if (!instructed && !byType("response").length) {
    notice("How this works", { instructions: DATA.instructions, start: true });
    return;
  }
  present(trials()[index]);
}

function loadImage(src) {
  return new Promise((resolve, reject) => {
    const img = new Image();
    img.onload = () => resolve(img);
    img.onerror = () => reject(new Error("an image could not be shown"));
    img.src = src;
  });
}

async function present(trial) {
  const L = DATA.layout;
  const stage = $("stage");
  const w = window.innerWidth, h = window.innerHeight;
  const k = Math.min(w / L.screen[0], h / L.screen[1]);
  const dpr = window.devicePixelRatio || 1;
  stage.width = Math.round(w * dpr);
  stage.height = Math.round(h * dpr);
  const ctx = stage.getContext("2d");
  ctx.setTransform(dpr * k, 0, 0, dpr * k, 0, 0);
  ctx.fillStyle = "#111";
  ctx.fillRect(0, 0, L.screen[0], L.screen[1]);
  for (const side of ["left", "right"]) {
    const cond = side === "left" ? trial.left : trial.right;
    const img = await loadImage(DATA.images[`${cond}|${trial.garment}`]);
    const [px, py, pw, ph] = L.panels[side];
    const [rx, ry, rw, rh] = DATA.rects[`${cond}|${trial.garment}`];
    ctx.save();
    ctx.beginPath();
    ctx.rect(px, py, pw, ph);
    ctx.clip();
    ctx.drawImage(img, px + rx, py + ry, rw, rh);
    ctx.restore();
    const b = $(`choose-${side}`);
    const [bx, by, bw, bh] = L.buttons[side];
    Object.assign(b.style, { left: `${bx * k}px`, top: `${by * k}px`, width: `${bw * k}px`, height: `${bh * k}px` });
    b.classList.remove("chosen");
    b.disabled = false;
  }
  const band = $("band");
  const [qx, qy, qw, qh] = L.question;
  Object.assign(band.style, { left: `${qx * k}px`, top: `${qy * k}px`, width: `${qw * k}px`, height: `${qh * k}px`,
    fontSize: `${Math.max(12, Math.min(24, qh * k * 0.32))}px` });
  const tests = trials().filter((t) => t.block === "test");
  $("question").textContent = DATA.question;
  $("progress").textContent = trial.block === "warmup" ? "practice" : `${tests.indexOf(trial) + 1} / ${tests.length}`;
  $("instructions-line").textContent = trial.block === "warmup" ? "Practice pair: it is not counted." : "";
  show(null);
  const shown = append("shown", { participant: code, session: 1, trial: trial.index, token: `web-${trial.index}`,
    page: bootId, reshown: false, ...now() });
  const limit = trial.block === "test" ? DATA.time_limit_s : null;
  current = { trial, shown, limit, t0: performance.now() };
  if (limit !== null) current.timer = setTimeout(() => respond(null), limit * 1000);
}

function respond(side) {
  const c = current;
  if (!c) return;
  current = null;
  clearTimeout(c.timer);
  for (const s of ["left", "right"]) $(`choose-${s}`).disabled = true;
  if (side) $(`choose-${side}`).classList.add("chosen");
  const t = c.trial;
  const ref = session.schedule.reference;
  const chosen = side ? (side === "left" ? t.left : t.right) : null;
  const stamp = now();
  const bundles = {};
  for (const [s, cond] of [["left", t.left], ["right", t.right]]) {
    bundles[s] = { condition: cond, ...session.bundles[cond][t.garment] };
  }
  append("response", {
    study_id: DATA.study_id, participant: code, session: 1, trial: t.index, block: t.block, garment: t.garment,
    half: t.half, reference: ref, comparison: t.comparison, left: t.left, right: t.right,
    reference_side: t.left === ref ? "left" : "right", choice: side, chosen,
    chose_reference: chosen === null ? null : chosen === ref, timeout: side === null,
    rt_s: side === null ? null : secs(performance.now() - c.t0), time_limit_s: c.limit, bundles,
    software: DATA.software, shown_wall: c.shown.wall, shown_mono: c.shown.mono, ...stamp,
  });
  if (side === null && DATA.timeout_notice_s > 0) {
    notice("Time is up for this pair, so no answer was recorded. The next pair follows.");
    setTimeout(advance, DATA.timeout_notice_s * 1000);
  } else {
    setTimeout(advance, 150);
  }
}

// --- wiring -----------------------------------------------------------------------------------------------------
for (const side of ["left", "right"]) {
  $(`choose-${side}`).addEventListener("pointerdown", (ev) => { ev.preventDefault(); respond(side); });
}
$("start").addEventListener("click", () => { instructed = true; advance(); });
$("consent-yes").addEventListener("click", () => {
  append("consent", { participant: code, session: 1, agreed: true, version: DATA.consent.version,
    text_sha256: DATA.consent.sha256, ...now() });
  advance();
});
$("consent-no").addEventListener("click", () => {
  append("consent", { participant: code, session: 1, agreed: false, version: DATA.consent.version,
    text_sha256: DATA.consent.sha256, ...now() });
  append("end", { participant: code, session: 1, reason: "no_consent", ...now() });
  advance();
});
$("about-go").addEventListener("click", () => {
  const answers = {};
  for (const el of $("about-form").elements) answers[el.name] = el.value === "" ? null : el.value;
  append("demographics", { participant: code, session: 1, answers, ...now() });
  advance();
});
$("download").addEventListener("click", () => {
  const text = records.map((r) => canon(r) + "\n").join("");
  const a = document.createElement("a");
  a.href = URL.createObjectURL(new Blob([text], { type: "application/x-ndjson" }));
  a.download = `${DATA.study_id}-${code}.jsonl`;
  document.body.append(a);
  a.click();
  a.remove();
});
$("code-form").addEventListener("submit", (ev) => {
  ev.preventDefault();
  const c = $("code-input").value.trim();
  if (DATA.sessions[c]) begin(c);
  else $("code-error").textContent = "This code is not part of the study. Please check it.";
});

const fromUrl = new URLSearchParams(location.search).get("participant");
if (fromUrl && DATA.sessions[fromUrl]) begin(fromUrl);
else show("code");
