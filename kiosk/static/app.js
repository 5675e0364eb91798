// The shopper's page: draw a garment, see it synthesized where it was drawn, feel its fabric.
//
// Drawing and feeling are two modes, because on a haptic screen both are the same gesture (a finger sliding):
// in Draw mode a touch adds ink; in Feel mode a touch only shows where the finger is and never changes the sketch,
// never asks for inference and never touches the friction frame on the device. The page switches to Feel by
// itself when a drawing first closes into a garment. Once a pen has touched the screen the pen always draws and a
// finger follows the toggle (Feel after the pen's first touch).
//
// Coordinates are screen pixels (the haptic panel's pixels). In kiosk mode the page fills the screen from its
// top-left corner, so screen = CSS px x devicePixelRatio; `?origin=X,Y` states another viewport origin.
// The page sends strokes (never rasters): the daemon rasterizes them with the runtime contract. Every request
// reports the panel rectangle the page shows; the response says where the visual goes (the planned region, in
// screen pixels), and the daemon puts the friction map exactly there on the haptic screen.
// While a stroke is drawn the page asks for previews (one in flight, latest wins); at stroke end, the full result.
//
// The store loop: after `page.idle_timeout_s` without a touch the drawing and the friction frame are cleared and the
// attract screen draws the catalogue's reference sketches; a touch starts a new session. Usage events (counts
// only, no coordinates or strokes) go to /api/usage.
"use strict";

const $ = (id) => document.getElementById(id);
const stage = $("stage");
const ctx = stage.getContext("2d");
const noticeEl = $("notice"), hintEl = $("hint"), toastEl = $("toast"), fingerEl = $("finger");
const garmentsEl = $("garments"), fabricEl = $("fabric"), attractEl = $("attract");
const params = new URLSearchParams(location.search);
const origin = (params.get("origin") || "0,0").split(",").map((v) => Number(v) || 0);
const client = "page-" + Math.random().toString(36).slice(2, 10);
const NOT_ANSWERING = "the kiosk service is not answering";

const state = {
  bundles: [], garment: null, defaultGarment: null,
  strokes: [],          // finished strokes: arrays of [x, y] in screen px
  current: null,        // the stroke being drawn
  currentId: null,      // its pointer
  currentType: null,    // and the pointer's kind (touch, pen, mouse)
  moved: false,         // the stroke went farther than a tap
  base: false,          // the garment's own sketch under the strokes
  visual: null,         // {bitmap, rect, frame, preview, alpha}
  settled: null,        // the last full (non-preview) visual: what a cancelled stroke falls back to
  reference: null,      // {img, rect}
  seq: 0, applied: 0,   // request sequence numbers: a late preview never overwrites a newer result
  previewInFlight: false, dirty: false,
  requestNotice: null, serverNotices: [],
  mode: "draw",         // what a touch on the canvas does: "draw" adds ink, "feel" only feels
  penSeen: false,
  pointers: new Map(),  // pointers down anywhere on the page: id -> pointerType
  blocked: false,       // a second touch cancelled the stroke: nothing draws until every finger is up
  feelId: null,         // the pointer feeling the garment
  garmentShown: false,  // the last full answer showed a garment
  attract: false,
  session: null,        // {startedAt, felt}
  lastActivity: performance.now(),
};
const stats = { previews: [], finals: [], refines: [], errors: 0, requests: 0, inFlight: 0, taps: 0, cancelled: 0,
  touches: { draw: 0, feel: 0 }, usage: [], idleResets: 0 };
let config = null;  // GET /api/page: timings and texts
const api = { state, stats, shown: null, lastMeta: null, ready: null, config: () => config,
  attract: () => attractArt.progress() };
window.vtkiosk = api;

function dpr() { return window.devicePixelRatio || 1; }
function panelRect() {
  return { x: origin[0], y: origin[1], w: Math.round(window.innerWidth * dpr()), h: Math.round(window.innerHeight * dpr()) };
}
function toScreen(ev) {
  const r = stage.getBoundingClientRect();
  const x = origin[0] + (ev.clientX - r.left) * dpr();
  const y = origin[1] + (ev.clientY - r.top) * dpr();
  return [Math.round(x * 10) / 10, Math.round(y * 10) / 10];
}
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

// -- drawing --------------------------------------------------------------------------------------------------------
function redraw() {
  ctx.setTransform(1, 0, 0, 1, 0, 0);
  ctx.clearRect(0, 0, stage.width, stage.height);
  if (state.visual) {
    const [x, y, w, h] = state.visual.rect;
    ctx.imageSmoothingEnabled = true;
    ctx.drawImage(state.visual.bitmap, x - origin[0], y - origin[1], w, h);
  }
  if (state.base && state.reference && state.reference.rect && state.reference.ink) {
    const [x, y, w, h] = state.reference.rect;
    ctx.globalAlpha = 0.7;
    ctx.drawImage(state.reference.ink, x - origin[0], y - origin[1], w, h);
    ctx.globalAlpha = 1;
  }
  ctx.strokeStyle = "rgba(25, 25, 35, 0.9)";
  ctx.lineWidth = 2;
  ctx.lineJoin = ctx.lineCap = "round";
  const strokes = state.current && state.moved ? state.strokes.concat([state.current]) : state.strokes;
  for (const s of strokes) {
    if (!s.length) continue;
    ctx.beginPath();
    ctx.moveTo(s[0][0] - origin[0], s[0][1] - origin[1]);
    for (const p of s.slice(1)) ctx.lineTo(p[0] - origin[0], p[1] - origin[1]);
    ctx.stroke();
  }
}

function resize() {
  stage.width = Math.round(window.innerWidth * dpr());
  stage.height = Math.round(window.innerHeight * dpr());
  redraw();
}

// -- what the page says ---------------------------------------------------------------------------------------------
function applyTexts() {
  for (const el of document.querySelectorAll("[data-text]")) el.textContent = config.texts[el.dataset.text];
}

function fabricName() {
  const b = state.bundles.find((x) => x.id === state.garment);
  return b ? b.display_name : "";
}

// The hint says exactly what a touch on the canvas does now.
function updateHint() {
  const t = config.texts;
  let text;
  // The pen's hint says a finger feels: true in Feel mode only (in Draw mode a finger draws, like the pen).
  if (state.penSeen && config.pen_draws && state.mode === "feel") text = t.hint_pen;
  else if (state.mode === "draw") text = state.garmentShown ? t.hint_draw : t.hint_draw_empty;
  else text = state.garmentShown ? t.hint_feel : t.hint_feel_empty;
  hintEl.textContent = text;
  $("fabric-name").textContent = fabricName();
  fabricEl.hidden = !(state.mode === "feel" && state.garmentShown);
}

let toastTimer = null;
function toast(text) {
  toastEl.textContent = text;
  toastEl.hidden = false;
  clearTimeout(toastTimer);
  toastTimer = setTimeout(() => { toastEl.hidden = true; }, 4000);
}

function setMode(mode) {
  if (mode !== "draw" && mode !== "feel") return;
  if (state.current) cancelStroke();
  state.mode = mode;
  document.body.dataset.mode = mode;
  for (const b of $("modes").children) b.setAttribute("aria-checked", String(b.dataset.mode === mode));
  fingerEl.hidden = true;
  state.feelId = null;
  toastEl.hidden = true;
  updateHint();
}

function showNotices() {
  const all = [state.requestNotice, ...state.serverNotices].filter(Boolean);
  noticeEl.textContent = [...new Set(all)].join(" \u00b7 ");
  noticeEl.hidden = all.length === 0;
}

// -- anonymous usage ------------------------------------------------------------------------------------------------
function usage(ev) {
  stats.usage.push(ev.event);
  fetch("/api/usage", { method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(ev),
    keepalive: true }).catch(() => {});
}

function startSession() {
  state.session = { startedAt: performance.now(), felt: false };
  usage({ event: "session" });
}

// -- talking to the daemon -----------------------------------------------------------------------------------------
// `stats.inFlight` counts renders not yet handled to the end (a refinement is asked for before its final's count
// drops), so 0 means the page shows the answer to its last request.
async function render(mode) {
  stats.inFlight++;
  try {
    await renderOnce(mode);
  } finally {
    stats.inFlight--;
  }
}

async function renderOnce(mode) {
  if (!state.garment) return;
  const seq = ++state.seq;
  stats.requests++;
  const panel = panelRect();
  const strokes = state.current && state.moved ? state.strokes.concat([state.current]) : state.strokes;
  const body = JSON.stringify({ garment: state.garment, panel, screen: [panel.x + panel.w, panel.y + panel.h],
    strokes, base: state.base, mode, client });
  const t0 = performance.now();
  let res;
  try {
    res = await fetch("/api/render", { method: "POST", headers: { "Content-Type": "application/json" }, body });
  } catch (err) {
    stats.errors++;
    state.requestNotice = NOT_ANSWERING;
    showNotices();
    return;
  }
  if (!res.ok) {
    stats.errors++;
    const e = await res.json().catch(() => ({}));
    state.requestNotice = e.error || `the kiosk answered HTTP ${res.status}`;
    showNotices();
    return;
  }
  // A request replaced by a newer one before it ran is answered {"superseded": true} as JSON; only frames are binary.
  if ((res.headers.get("Content-Type") || "").startsWith("application/json")) return;
  const buf = await res.arrayBuffer();
  const n = new DataView(buf).getUint32(0, true);
  const meta = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, 4, n)));
  if (meta.superseded || seq < state.applied) return;
  state.applied = seq;
  const p = meta.panels[0];
  if (p.status === "empty") {
    state.visual = null;
  } else if (p.status === "ok" && p.visual) {
    const pixels = new Uint8ClampedArray(buf, 4 + n + p.visual.offset, p.visual.length);
    const bitmap = await createImageBitmap(new ImageData(pixels, p.visual.size[0], p.visual.size[1]));
    if (seq < state.applied) return;
    state.visual = { bitmap, rect: p.visual.rect, frame: meta.frame, preview: meta.preview,
      alpha: { pixels, w: p.visual.size[0], h: p.visual.size[1] } };
  }
  if (state.reference && p.reference) state.reference.rect = p.reference.rect;
  state.requestNotice = p.notice || null;
  state.serverNotices = meta.notices || [];
  showNotices();
  redraw();
  const ms = performance.now() - t0;
  ({ preview: stats.previews, final: stats.finals, refine: stats.refines })[meta.mode]
    .push({ at: performance.now(), ms, frame: meta.frame });
  api.lastMeta = meta;
  if (!meta.preview) {
    state.settled = state.visual;
    state.lastActivity = performance.now();  // a shopper watching their garment appear is not idle
    const before = state.garmentShown;
    if (p.status !== "kept") state.garmentShown = p.status === "ok";
    // The drawing just closed into a garment: the next thing to do is to feel it.
    if (!before && state.garmentShown && config.auto_feel && state.mode === "draw" && !state.attract) {
      setMode("feel");
      toast(config.texts.ready);
    }
    updateHint();
    api.shown = { frame: meta.frame, mode: meta.mode, device_frame: meta.device_frame, status: p.status,
      visual: state.visual ? state.visual.rect : null, friction: p.friction ? p.friction.rect : null, panel };
  }
  // The stroke end was answered quickly at the preview resolution: ask for the full resolution now, unless the
  // finger is already drawing again (the next stroke end will).
  if (meta.refine && meta.mode === "final" && !state.current && seq === state.seq) render("refine");
}

function pumpPreview() {
  if (!state.current || !state.moved || state.previewInFlight || !state.dirty) return;
  state.previewInFlight = true;
  state.dirty = false;
  render("preview").finally(() => {
    state.previewInFlight = false;
    if (state.current && state.dirty) requestAnimationFrame(pumpPreview);
  });
}

// -- input ----------------------------------------------------------------------------------------------------------
function drawsWith(ev) {
  if (ev.pointerType === "pen" && config.pen_draws) return true;
  return state.mode === "draw";
}

// The stroke in progress is dropped (a second finger or a palm came down, or the browser gave the touch up):
// the sketch goes back to what it was and late previews of the dropped stroke are ignored.
function cancelStroke() {
  if (!state.current) return;
  state.current = null;
  state.currentId = null;
  state.applied = ++state.seq;
  state.visual = state.settled;
  stats.cancelled++;
  redraw();
}

function touchedGarment(pt) {
  const v = state.settled;
  if (!v || !v.alpha) return false;
  const [x, y, w, h] = v.rect;
  const u = Math.floor((pt[0] - x) / w * v.alpha.w), r = Math.floor((pt[1] - y) / h * v.alpha.h);
  if (u < 0 || r < 0 || u >= v.alpha.w || r >= v.alpha.h) return false;
  return v.alpha.pixels[(r * v.alpha.w + u) * 4 + 3] > 0;
}

function feel(ev) {
  fingerEl.style.transform = `translate(${ev.clientX}px, ${ev.clientY}px)`;
  fingerEl.hidden = false;
  const s = state.session;
  if (s && !s.felt && touchedGarment(toScreen(ev))) {
    s.felt = true;
    usage({ event: "felt", seconds: Math.round((performance.now() - s.startedAt) / 100) / 10 });
  }
}

// Every pointer anywhere: activity for the idle timer, and a second touch while drawing cancels the stroke.
// A pen's stroke goes on when a palm rests beside it (the palm only feels); a finger's stroke does not.
document.addEventListener("pointerdown", (ev) => {
  state.lastActivity = performance.now();
  // A primary pointer means no other pointer of its kind is down: forget any whose "up" never came.
  if (ev.isPrimary) for (const [id, type] of state.pointers) if (type === ev.pointerType) state.pointers.delete(id);
  state.pointers.set(ev.pointerId, ev.pointerType);
  if (state.current && ev.pointerId !== state.currentId && !(state.currentType === "pen" && ev.pointerType !== "pen")) {
    state.blocked = true;
    cancelStroke();
  }
}, true);
document.addEventListener("pointermove", () => { state.lastActivity = performance.now(); }, true);
for (const type of ["pointerup", "pointercancel"]) {
  document.addEventListener(type, (ev) => {
    state.lastActivity = performance.now();
    state.pointers.delete(ev.pointerId);
    if (state.pointers.size === 0) state.blocked = false;
  }, true);
}
document.addEventListener("contextmenu", (ev) => ev.preventDefault());

stage.addEventListener("pointerdown", (ev) => {
  if (!config || state.attract || (ev.button !== undefined && ev.button > 0)) return;
  if (!ev.isPrimary || state.blocked || state.current) return;
  if (ev.pointerType === "pen" && config.pen_draws && !state.penSeen) {
    state.penSeen = true;  // this panel has a pen: it draws, and a finger feels
    setMode("feel");
  }
  const draws = drawsWith(ev);
  stats.touches[draws ? "draw" : "feel"]++;
  usage({ event: "touch", mode: draws ? "draw" : "feel" });
  stage.setPointerCapture(ev.pointerId);
  if (!draws) {
    state.feelId = ev.pointerId;
    feel(ev);
    return;
  }
  state.current = [toScreen(ev)];
  state.currentId = ev.pointerId;
  state.currentType = ev.pointerType;
  state.moved = false;
});
stage.addEventListener("pointermove", (ev) => {
  if (ev.pointerId === state.feelId) { feel(ev); return; }
  if (!state.current || ev.pointerId !== state.currentId) return;
  const events = ev.getCoalescedEvents ? ev.getCoalescedEvents() : [ev];
  for (const e of events.length ? events : [ev]) state.current.push(toScreen(e));
  if (!state.moved) {
    // A tap leaves no ink: the stroke counts only once it went farther than tap_max_px from where it began.
    const [x0, y0] = state.current[0], lim = config.tap_max_px * dpr();
    state.moved = state.current.some(([x, y]) => Math.hypot(x - x0, y - y0) > lim);
    if (!state.moved) return;
  }
  state.dirty = true;
  redraw();
  pumpPreview();
});
stage.addEventListener("pointerup", (ev) => {
  if (ev.pointerId === state.feelId) {
    state.feelId = null;
    fingerEl.hidden = true;
    return;
  }
  if (!state.current || ev.pointerId !== state.currentId) return;
  state.current.push(toScreen(ev));
  const stroke = state.current;
  state.current = null;
  state.currentId = null;
  if (!state.moved) {  // a tap: nothing drawn, nothing sent
    stats.taps++;
    redraw();
    return;
  }
  state.strokes.push(stroke);
  redraw();
  render("final");
});
// The browser took the pointer away (it lost capture without an "up"): treat it like a cancel.
stage.addEventListener("lostpointercapture", (ev) => {
  if (ev.pointerId === state.feelId) {
    state.feelId = null;
    fingerEl.hidden = true;
  } else if (ev.pointerId === state.currentId) {
    cancelStroke();
  }
});
stage.addEventListener("pointercancel", (ev) => {
  if (ev.pointerId === state.feelId) {
    state.feelId = null;
    fingerEl.hidden = true;
  } else if (ev.pointerId === state.currentId) {
    cancelStroke();
  }
});

// Buttons act when a pointer that went down on them is released over them, not on the browser's click: Chromium
// swallows the click of a tap that lands while a flick is still coasting (the tap that stops a fling), and a
// shopper's quick tap on Undo, on Draw or on the next fabric right after a slide is exactly that tap. A click with
// no pointer behind it (detail 0: the keyboard, assistive technology) still acts.
const presses = new Map();  // pointerId -> the button it went down on
function onPress(el, fn) {
  el.addEventListener("pointerdown", (ev) => { if (ev.button === 0) presses.set(ev.pointerId, el); });
  el.addEventListener("pointerup", (ev) => {
    if (presses.get(ev.pointerId) !== el) return;
    presses.delete(ev.pointerId);
    const r = el.getBoundingClientRect();  // released over the button: a finger that slid off takes it back
    if (ev.clientX >= r.left && ev.clientX <= r.right && ev.clientY >= r.top && ev.clientY <= r.bottom) fn();
  });
  el.addEventListener("click", (ev) => { if (ev.detail === 0) fn(); });
}
// Bubble phase, after the button's own handler: a press released elsewhere (or taken by a scroll) is forgotten.
for (const type of ["pointerup", "pointercancel"]) {
  document.addEventListener(type, (ev) => presses.delete(ev.pointerId));
}

for (const b of $("modes").children) onPress(b, () => setMode(b.dataset.mode));
onPress($("undo"), () => {
  if (state.strokes.length) state.strokes.pop();
  else state.base = false;
  redraw();
  render("final");
});
onPress($("clear"), () => {
  state.strokes = [];
  state.base = false;
  state.visual = null;
  redraw();
  render("final");
});
onPress($("reference"), async () => {
  state.strokes = [];
  state.base = true;
  await loadReference();
  render("final");
});

async function loadReference() {
  const img = new Image();
  img.src = `/api/bundles/${encodeURIComponent(state.garment)}/sketch.png`;
  const ok = await img.decode().then(() => true, () => false);
  const ink = ok ? inkOf(img) : null;
  state.reference = { img, ink, rect: state.reference ? state.reference.rect : null };
}

// The sketch's ink only (paper becomes transparent), so it lies over a picture without hiding it.
function inkOf(img) {
  const ink = document.createElement("canvas");
  ink.width = img.naturalWidth;
  ink.height = img.naturalHeight;
  const c = ink.getContext("2d");
  c.drawImage(img, 0, 0);
  const px = c.getImageData(0, 0, ink.width, ink.height);
  for (let i = 0; i < px.data.length; i += 4) {
    px.data[i + 3] = 255 - px.data[i];
    px.data[i] = px.data[i + 1] = px.data[i + 2] = 25;
  }
  c.putImageData(px, 0, 0);
  return ink;
}

function markGarment(id) {
  state.garment = id;
  for (const b of garmentsEl.children) b.setAttribute("aria-checked", String(b.dataset.id === id));
  updateHint();
}

// A tap on the catalogue: the drawing on the canvas is made in that garment's fabric; with nothing drawn, the
// garment's own outline is laid out, so a shopper who only picks can feel it at once.
async function pickGarment(id) {
  markGarment(id);
  if (!state.strokes.length && !state.base) state.base = true;
  if (state.base) await loadReference();
  await render("final");
}

async function loadBundles() {
  const res = await fetch("/api/bundles");
  if (!res.ok) throw new Error(`HTTP ${res.status}`);
  const data = await res.json();
  state.bundles = data.bundles;
  state.defaultGarment = data.default;
  garmentsEl.textContent = "";
  for (const b of data.bundles) {
    const btn = document.createElement("button");
    btn.type = "button";
    btn.dataset.id = b.id;
    btn.setAttribute("role", "radio");
    const thumb = ["visual", "sketch"].find((a) => b.assets.includes(a));
    if (thumb) {
      const img = document.createElement("img");
      img.alt = "";
      img.src = `/api/bundles/${encodeURIComponent(b.id)}/${thumb}.png`;
      btn.appendChild(img);
    }
    const name = document.createElement("span");
    name.textContent = b.display_name;
    btn.appendChild(name);
    onPress(btn, () => pickGarment(b.id));
    garmentsEl.appendChild(btn);
  }
  if (data.default) {
    markGarment(data.default);
    await render("final");  // `ready` resolves after the first (empty) frame, which also blanks the device
  }
  attractArt.prepare(data.bundles);
}

// -- the store loop -------------------------------------------------------------------------------------------------
function showAttract() {
  state.attract = true;
  attractEl.hidden = false;
  attractArt.start();
}

attractEl.addEventListener("pointerdown", (ev) => {
  ev.preventDefault();
  state.attract = false;
  attractEl.hidden = true;
  attractArt.stop();
  state.lastActivity = performance.now();
  startSession();
});

// Nobody touched the screen for idle_timeout_s: the next shopper must not see (or feel) the last one's drawing.
function idleReset() {
  stats.idleResets++;
  usage({ event: "idle_reset" });
  state.session = null;
  state.strokes = [];
  state.current = null;
  state.currentId = null;
  state.base = false;
  state.visual = state.settled = null;
  state.garmentShown = false;
  state.applied = ++state.seq;  // answers still on their way belong to the last shopper
  setMode(state.penSeen && config.pen_draws ? "feel" : "draw");
  if (state.defaultGarment) markGarment(state.defaultGarment);
  showAttract();
  redraw();
  render("final");  // an empty frame: the friction frame on the device is cleared too
}

function checkIdle() {
  if (!config || state.attract || state.current || state.feelId !== null) return;  // a resting finger is a shopper
  if (performance.now() - state.lastActivity > config.idle_timeout_s * 1000) idleReset();
}

// The attract screen draws each catalogue garment's reference sketch line by line (a sweep around its centre),
// then fills it in with the garment's picture. Reference assets only: no inference while nobody is there.
const attractArt = (() => {
  const canvas = $("attract-art");
  const c = canvas.getContext("2d");
  let items = [], raf = 0, t0 = 0;

  async function load(b) {
    const get = async (name) => {
      if (!b.assets.includes(name)) return null;
      const img = new Image();
      img.src = `/api/bundles/${encodeURIComponent(b.id)}/${name}.png`;
      return img.decode().then(() => img, () => null);
    };
    const [sketch, visual, mask] = await Promise.all([get("sketch"), get("visual"), get("mask")]);
    if (!sketch) return null;
    const w = sketch.naturalWidth, h = sketch.naturalHeight;
    const ink = inkOf(sketch).getContext("2d").getImageData(0, 0, w, h);
    let sx = 0, sy = 0, sn = 0;
    for (let i = 0; i < w * h; i++) if (ink.data[i * 4 + 3] > 64) { sx += i % w; sy += Math.floor(i / w); sn++; }
    const cx = sn ? sx / sn : w / 2, cy = sn ? sy / sn : h / 2;
    const order = new Float32Array(w * h);  // when each ink pixel appears: clockwise from the top
    for (let i = 0; i < w * h; i++) {
      const a = Math.atan2(Math.floor(i / w) - cy, i % w - cx) + Math.PI / 2;
      order[i] = (a < 0 ? a + 2 * Math.PI : a) / (2 * Math.PI);
    }
    let fill = null;
    if (visual) {
      fill = document.createElement("canvas");
      fill.width = w;
      fill.height = h;
      const f = fill.getContext("2d");
      f.drawImage(visual, 0, 0, w, h);
      if (mask) {  // only the garment, not its photo background
        const m = document.createElement("canvas");
        m.width = w;
        m.height = h;
        const mc = m.getContext("2d");
        mc.drawImage(mask, 0, 0, w, h);
        const md = mc.getImageData(0, 0, w, h), fd = f.getImageData(0, 0, w, h);
        for (let i = 0; i < w * h; i++) fd.data[i * 4 + 3] = md.data[i * 4];
        f.putImageData(fd, 0, 0);
      }
    }
    const layer = document.createElement("canvas");
    layer.width = w;
    layer.height = h;
    return { name: b.display_name, w, h, ink, order, fill, layer, shown: new ImageData(w, h) };
  }

  let last = 0;
  function frame(now) {
    raf = requestAnimationFrame(frame);
    if (now - last < 1000 / 30) return;  // 30 frames/s is smooth enough for a line being drawn
    last = now;
    const r = canvas.getBoundingClientRect();
    const W = Math.round(r.width * dpr()), H = Math.round(r.height * dpr());
    if (canvas.width !== W || canvas.height !== H) { canvas.width = W; canvas.height = H; }
    c.clearRect(0, 0, W, H);
    if (!items.length) return;
    const period = config.attract_garment_s * 1000;
    const t = Math.max(0, now - t0);  // a frame's timestamp can precede a clock restarted by prepare()
    const it = items[Math.floor(t / period) % items.length];
    const p = (t % period) / period;
    const k = Math.min(W / it.w, H / it.h);
    const x = (W - it.w * k) / 2, y = (H - it.h * k) / 2;
    c.globalAlpha = p > 0.92 ? Math.max(0, (1 - p) / 0.08) : 1;
    const fillIn = Math.min(1, Math.max(0, (p - 0.5) / 0.25));
    if (it.fill && fillIn > 0) {
      c.globalAlpha *= fillIn;
      c.drawImage(it.fill, x, y, it.w * k, it.h * k);
      c.globalAlpha = p > 0.92 ? Math.max(0, (1 - p) / 0.08) : 1;
    }
    // The ink layer changes in 100 steps of the sweep and 20 of the fade: a kiosk's idle CPU stays idle.
    const drawn = Math.round(Math.min(1, p / 0.45) * 100) / 100, fade = Math.round(fillIn * 20) / 20;
    if (it.drawn !== drawn || it.fade !== fade) {
      it.drawn = drawn;
      it.fade = fade;
      const src = it.ink.data, dst = it.shown.data;
      for (let i = 0; i < it.w * it.h; i++) {
        dst[i * 4] = dst[i * 4 + 1] = dst[i * 4 + 2] = 25;
        dst[i * 4 + 3] = it.order[i] <= drawn ? src[i * 4 + 3] * (1 - 0.6 * fade) : 0;
      }
      it.layer.getContext("2d").putImageData(it.shown, 0, 0);
    }
    c.drawImage(it.layer, x, y, it.w * k, it.h * k);
    c.globalAlpha = 1;
  }

  return {
    async prepare(bundles) {
      items = (await Promise.all(bundles.map(load))).filter(Boolean);
      t0 = performance.now();  // start with the first garment's first line
    },
    // Which garment is on the attract screen and how far it is (0: first line, 1: faded out); null when hidden.
    progress() {
      if (!raf || !items.length) return null;
      const period = config.attract_garment_s * 1000, t = performance.now() - t0;
      return { garment: items[Math.floor(t / period) % items.length].name, at: (t % period) / period };
    },
    start() { if (!raf) { t0 = performance.now(); raf = requestAnimationFrame(frame); } },
    stop() { cancelAnimationFrame(raf); raf = 0; },
  };
})();

async function pollStatus() {
  try {
    const s = await (await fetch("/api/status")).json();
    state.serverNotices = s.notices || [];
    if (state.requestNotice === NOT_ANSWERING) state.requestNotice = null;
  } catch (err) {
    state.requestNotice = NOT_ANSWERING;
  }
  showNotices();
}

// The page waits for the daemon (a kiosk browser may start first) and then opens on the attract screen.
async function boot() {
  for (;;) {
    try {
      const res = await fetch("/api/page");
      if (!res.ok) throw new Error(`HTTP ${res.status}`);
      config = await res.json();
      applyTexts();
      updateHint();
      showAttract();
      await loadBundles();
      state.requestNotice = null;
      showNotices();
      return;
    } catch (err) {
      state.requestNotice = NOT_ANSWERING;
      showNotices();
      await sleep(2000);
    }
  }
}

window.addEventListener("resize", () => { resize(); if (config) render("final"); });
resize();
api.ready = boot();
setInterval(pollStatus, 2000);
setInterval(checkIdle, 250);
