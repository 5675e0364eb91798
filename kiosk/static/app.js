// The kiosk page: draw a garment with a finger, see the synthesized garment where it was drawn, feel it.
//
// Coordinates are screen pixels (the haptic panel's pixels). In kiosk mode the page fills the screen from its
// top-left corner, so screen = CSS px x devicePixelRatio; `?origin=X,Y` states another viewport origin.
// The page sends strokes (never rasters): the daemon rasterizes them with the runtime contract. Every request
// reports the panel rectangle the page shows; the response says where the visual goes (the planned region, in
// screen pixels), and the daemon puts the friction map exactly there on the haptic screen.
// While a stroke is drawn the page asks for previews (one in flight, latest wins); at stroke end, the full result.
"use strict";

const stage = document.getElementById("stage");
const ctx = stage.getContext("2d");
const noticeEl = document.getElementById("notice");
const hintEl = document.getElementById("hint");
const garmentsEl = document.getElementById("garments");
const params = new URLSearchParams(location.search);
const origin = (params.get("origin") || "0,0").split(",").map((v) => Number(v) || 0);
const client = "page-" + Math.random().toString(36).slice(2, 10);

const state = {
  bundles: [], garment: null,
  strokes: [],          // finished strokes: arrays of [x, y] in screen px
  current: null,        // the stroke being drawn
  base: false,          // the garment's own sketch under the strokes
  visual: null,         // {bitmap, rect, frame, preview}
  reference: null,      // {img, rect}
  seq: 0, applied: 0,   // request sequence numbers: a late preview never overwrites a newer result
  previewInFlight: false, dirty: false,
  requestNotice: null, serverNotices: [],
};
const stats = { previews: [], finals: [], refines: [], errors: 0 };
const api = { state, stats, shown: null, lastMeta: null, ready: null };
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
  for (const s of state.current ? state.strokes.concat([state.current]) : state.strokes) {
    if (!s.length) continue;
    ctx.beginPath();
    ctx.moveTo(s[0][0] - origin[0], s[0][1] - origin[1]);
    if (s.length === 1) ctx.lineTo(s[0][0] - origin[0] + 0.01, s[0][1] - origin[1]);  // a tap is a dot
    for (const p of s.slice(1)) ctx.lineTo(p[0] - origin[0], p[1] - origin[1]);
    ctx.stroke();
  }
}

function resize() {
  stage.width = Math.round(window.innerWidth * dpr());
  stage.height = Math.round(window.innerHeight * dpr());
  redraw();
}

// -- talking to the daemon -----------------------------------------------------------------------------------------
function showNotices() {
  const all = [state.requestNotice, ...state.serverNotices].filter(Boolean);
  noticeEl.textContent = [...new Set(all)].join(" \u00b7 ");
  noticeEl.hidden = all.length === 0;
}

async function render(mode) {
  if (!state.garment) return;
  const seq = ++state.seq;
  const panel = panelRect();
  const strokes = state.current ? state.strokes.concat([state.current]) : state.strokes;
  const body = JSON.stringify({ garment: state.garment, panel, screen: [panel.x + panel.w, panel.y + panel.h],
    strokes, base: state.base, mode, client });
  const t0 = performance.now();
  let res;
  try {
    res = await fetch("/api/render", { method: "POST", headers: { "Content-Type": "application/json" }, body });
  } catch (err) {
    stats.errors++;
    state.requestNotice = "the kiosk service is not answering";
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
    state.visual = { bitmap, rect: p.visual.rect, frame: meta.frame, preview: meta.preview };
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
    api.shown = { frame: meta.frame, mode: meta.mode, device_frame: meta.device_frame, status: p.status,
      visual: state.visual ? state.visual.rect : null, friction: p.friction ? p.friction.rect : null, panel };
  }
  // The stroke end was answered quickly at the preview resolution: ask for the full resolution now, unless the
  // finger is already drawing again (the next stroke end will).
  if (meta.refine && meta.mode === "final" && !state.current && seq === state.seq) render("refine");
}

function pumpPreview() {
  if (!state.current || state.previewInFlight || !state.dirty) return;
  state.previewInFlight = true;
  state.dirty = false;
  render("preview").finally(() => {
    state.previewInFlight = false;
    if (state.current && state.dirty) requestAnimationFrame(pumpPreview);
  });
}

// -- input ----------------------------------------------------------------------------------------------------------
stage.addEventListener("pointerdown", (ev) => {
  if (ev.button !== undefined && ev.button > 0) return;
  stage.setPointerCapture(ev.pointerId);
  state.current = [toScreen(ev)];
  hintEl.hidden = true;
  state.dirty = true;
  redraw();
  pumpPreview();
});
stage.addEventListener("pointermove", (ev) => {
  if (!state.current) return;
  const events = ev.getCoalescedEvents ? ev.getCoalescedEvents() : [ev];
  for (const e of events.length ? events : [ev]) state.current.push(toScreen(e));
  state.dirty = true;
  redraw();
  pumpPreview();
});
function endStroke(ev) {
  if (!state.current) return;
  if (ev.type === "pointerup") state.current.push(toScreen(ev));
  state.strokes.push(state.current);
  state.current = null;
  redraw();
  render("final");
}
stage.addEventListener("pointerup", endStroke);
stage.addEventListener("pointercancel", endStroke);

document.getElementById("undo").addEventListener("click", () => {
  if (state.strokes.length) state.strokes.pop();
  else state.base = false;
  redraw();
  render("final");
});
document.getElementById("clear").addEventListener("click", () => {
  state.strokes = [];
  state.base = false;
  state.visual = null;
  redraw();
  render("final");
});
document.getElementById("reference").addEventListener("click", async () => {
  state.strokes = [];
  state.base = true;
  await loadReference();
  hintEl.hidden = true;
  render("final");
});

async function loadReference() {
  const img = new Image();
  img.src = `/api/bundles/${encodeURIComponent(state.garment)}/sketch.png`;
  const ok = await img.decode().then(() => true, () => false);
  let ink = null;
  if (ok) {  // ink only: paper becomes transparent, so the sketch lies over the picture without hiding it
    ink = document.createElement("canvas");
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
  }
  state.reference = { img, ink, rect: state.reference ? state.reference.rect : null };
}

async function selectGarment(id) {
  state.garment = id;
  for (const b of garmentsEl.children) b.setAttribute("aria-checked", String(b.dataset.id === id));
  if (state.base) await loadReference();
  await render("final");
}

async function loadBundles() {
  const res = await fetch("/api/bundles");
  const data = await res.json();
  state.bundles = data.bundles;
  garmentsEl.textContent = "";
  for (const b of data.bundles) {
    const btn = document.createElement("button");
    btn.type = "button";
    btn.dataset.id = b.id;
    btn.setAttribute("role", "radio");
    btn.textContent = b.display_name;
    btn.addEventListener("click", () => selectGarment(b.id));
    garmentsEl.appendChild(btn);
  }
  if (data.default) await selectGarment(data.default);  // `ready` resolves after the first (empty) frame
}

async function pollStatus() {
  try {
    const s = await (await fetch("/api/status")).json();
    state.serverNotices = s.notices || [];
    if (state.requestNotice === "the kiosk service is not answering") state.requestNotice = null;
  } catch (err) {
    state.requestNotice = "the kiosk service is not answering";
  }
  showNotices();
}

window.addEventListener("resize", () => { resize(); render("final"); });
resize();
api.ready = loadBundles();
setInterval(pollStatus, 2000);
