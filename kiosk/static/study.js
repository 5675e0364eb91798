// The A/B study page: both halves show the same ground-truth visual, the haptic screen renders a different
// friction map under each; the participant taps "left" or "right". The daemon is authoritative about time and
// trials: this page only shows what /api/study/trial says, tells the daemon when the trial is on screen
// (/api/study/shown), and sends the tap (/api/study/choice) with the trial's token.
"use strict";

const stage = document.getElementById("stage");
const ctx = stage.getContext("2d");
const notice = document.getElementById("notice");
const clock = document.getElementById("clock");
const question = document.getElementById("question");
const progress = document.getElementById("progress");
const buttons = { left: document.getElementById("choose-left"), right: document.getElementById("choose-right") };

let current = null;      // the trial on screen: {token, ...}
let deadline = null;     // performance.now() ms when the daemon's time limit ends (timed trials)
let busy = false;        // a tap is in flight
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
  return p;
}

function showNotice(text) {
  notice.textContent = text;
  notice.hidden = false;
  for (const b of Object.values(buttons)) b.disabled = true;
  clock.textContent = "";
}

// Screen pixels (the haptic panel's coordinates) -> CSS pixels of this page.
function fit(screen) {
  const w = window.innerWidth, h = window.innerHeight;
  return { k: Math.min(w / screen[0], h / screen[1]), w, h };
}

async function draw(trial) {
  const { k, w, h } = fit(trial.screen);
  const dpr = window.devicePixelRatio || 1;
  stage.width = Math.round(w * dpr);
  stage.height = Math.round(h * dpr);
  ctx.setTransform(dpr * k, 0, 0, dpr * k, 0, 0);
  ctx.fillStyle = "#111";
  ctx.fillRect(0, 0, trial.screen[0], trial.screen[1]);
  const img = await loadImage(trial.visual);
  for (const p of trial.panels) {
    const [x, y, pw, ph] = p.rect;
    ctx.save();
    ctx.beginPath();
    ctx.rect(x, y, pw, ph);
    ctx.clip();
    ctx.fillStyle = "#fff";
    ctx.fillRect(x, y, pw, ph);
    const pl = p.placement;
    ctx.imageSmoothingQuality = "high";
    ctx.drawImage(img, pl.x, pl.y, pl.size[0] * pl.scale, pl.size[1] * pl.scale);
    ctx.restore();
  }
  for (const b of trial.buttons) {
    const el = buttons[b.side];
    const [x, y, bw, bh] = b.rect;
    Object.assign(el.style, { left: `${x * k}px`, top: `${y * k}px`, width: `${bw * k}px`, height: `${bh * k}px` });
    el.classList.remove("chosen");
  }
}

async function present(trial) {
  current = trial;
  deadline = null;
  question.textContent = trial.question;
  progress.textContent = trial.block === "warmup" ? "practice" : `${trial.number} / ${trial.of}`;
  await draw(trial);
  notice.hidden = true;
  const shown = await api("POST", "/api/study/shown", { token: trial.token });
  if (shown.time_left_s !== null && shown.time_left_s !== undefined) {
    deadline = performance.now() + 1000 * shown.time_left_s;
  }
  busy = false;
  for (const b of Object.values(buttons)) b.disabled = false;
}

async function choose(side) {
  if (!current || busy) return;       // the daemon ignores (and logs) double taps too
  busy = true;
  for (const b of Object.values(buttons)) b.disabled = true;
  buttons[side].classList.add("chosen");
  const token = current.token;
  try {
    const res = await api("POST", "/api/study/choice", { token, side });
    if (!res.recorded) console.info("tap ignored:", res.ignored);
  } catch (err) {
    console.warn(err);
  }
  current = null;
  await poll();
}

async function poll() {
  let state;
  try {
    state = await api("GET", "/api/study/trial");
  } catch (err) {
    showNotice("The kiosk is not answering. Please wait for the experimenter.");
    return;
  }
  if (state.state === "trial") {
    if (!current || current.token !== state.trial.token) {
      try {
        await present(state.trial);
      } catch (err) {
        console.warn(err);
        current = null;
      }
    }
  } else {
    current = null;
    showNotice(state.notice || "Please wait for the experimenter.");
  }
}

function tick() {
  if (current && deadline !== null) {
    const left = Math.max(0, (deadline - performance.now()) / 1000);
    clock.textContent = `${Math.ceil(left)} s`;
    if (left <= 0 && !busy) {
      for (const b of Object.values(buttons)) b.disabled = true;
      clock.textContent = "time is up";
    }
  } else if (current) {
    clock.textContent = "";
  }
}

for (const b of Object.values(buttons)) {
  b.addEventListener("pointerdown", (ev) => { ev.preventDefault(); choose(b.dataset.side); });
}
window.addEventListener("resize", () => { if (current) draw(current); });
setInterval(() => { if (!busy) poll(); }, 500);
setInterval(tick, 100);
poll();
