// zcut labelling page. Vanilla JS + canvas, no build step.
// Data per frame: one binary bundle (valid mask, candidate cluster ids), a JPEG per view, and the
// annotator's current label (outliers L, reviewed R). L ⊆ R ⊆ valid is kept by every tool.
'use strict';

const BOOT = JSON.parse(document.getElementById('boot').textContent);
const TOKEN = BOOT.token;
const $ = (id) => document.getElementById(id);

function api(path, opts = {}) {
  const headers = Object.assign({}, opts.headers || {}, { 'X-Zcut-Token': TOKEN });
  return fetch(path, Object.assign({}, opts, { headers }));
}

async function fetchOk(path) {
  const r = await api(path);
  if (!r.ok) throw new Error(`${path}: HTTP ${r.status}`);
  return r;
}

// ------------------------------------------------------------------ the worker (fetch, decode, pack)
const worker = new Worker(`/static/worker.js?token=${encodeURIComponent(TOKEN)}`);
worker.postMessage({ type: 'token', token: TOKEN });
const pending = new Map();
let nextId = 1;
// a second worker only decodes JPEGs: the image decodes in parallel with the masks
const imageWorker = new Worker(`/static/worker.js?token=${encodeURIComponent(TOKEN)}`);
imageWorker.postMessage({ type: 'token', token: TOKEN });
worker.onmessage = imageWorker.onmessage = (e) => {
  const m = e.data, p = pending.get(m.id);
  if (!p) return;
  pending.delete(m.id);
  if (m.ok) p.resolve(m); else p.reject(new Error(m.error));
};
function call(msg, transfer = [], w = worker) {
  const id = nextId++;
  return new Promise((resolve, reject) => { pending.set(id, { resolve, reject }); w.postMessage({ ...msg, id }, transfer); });
}
function expectReply() {  // a second reply to one message (the frame's image): [id, promise]
  const id = nextId++;
  return [id, new Promise((resolve, reject) => pending.set(id, { resolve, reject }))];
}

// ------------------------------------------------------------------ state
const state = {
  annotator: localStorage.getItem('zcut.annotator') || BOOT.annotator,
  frames: [], total: 0, done: false,
  cur: null, tool: 'select', brush: 8,
  showZ: true, showS: true, showL: true, showH: false,
  zoom: 1, px: 0, py: 0, fitted: false,
};
const cache = new Map();  // index -> Promise<frame>
const CACHE_RADIUS = 2;
window.zcut = { switchTimes: [], acks: [], errors: [], loads: [] };

const COL_L = rgba(255, 30, 60, 200), COL_Z = rgba(255, 170, 0, 120), COL_S = rgba(40, 150, 255, 120);
const COL_ZS = rgba(190, 90, 255, 140), COL_UNREV = rgba(0, 0, 0, 150);
function rgba(r, g, b, a) { return ((a << 24) | (b << 16) | (g << 8) | r) >>> 0; }

// ------------------------------------------------------------------ loading frames
function flags() { return { showL: state.showL, showZ: state.showZ, showS: state.showS }; }
function sameFlags(a, b) { return a && a.showL === b.showL && a.showZ === b.showZ && a.showS === b.showS; }
function viewKind() { return state.showH ? 'height' : 'rgb'; }

function setLabel(fd, lab) {
  fd.rev = lab.rev; fd.L = lab.L; fd.R = lab.R; fd.hasR = lab.hasR;
  fd.committedL = fd.L.slice(); fd.committedR = fd.R.slice();
  fd.undo = []; fd.redo = []; fd.dirty = false; fd.conflict = 0;
}

async function loadLabel(fd) {
  setLabel(fd, await call({ type: 'label', index: fd.index, annotator: state.annotator, W: fd.W, H: fd.H }));
  fd.ovFlags = null;
}

function loadFrame(index) {
  if (cache.has(index)) return cache.get(index);
  const kind = viewKind();
  const p = (async () => {
    const t0 = performance.now();
    const [imageId, overlay] = expectReply();
    const image = call({ type: 'image', index, kind }, [], imageWorker);
    let m;
    try {
      m = await call({ type: 'frame', index, annotator: state.annotator, flags: flags(), imageId });
    } catch (e) {
      pending.delete(imageId);
      image.then((im) => im.bitmap.close(), () => {});
      throw e;
    }
    const t1 = performance.now();
    const h = m.header;
    const fd = {
      index, stamp: h.stamp_ns, W: h.width, H: h.height, header: h,
      valid: m.valid, zIds: m.zIds, sIds: m.sIds, bmp: {},
      saving: false, pendingSave: false, annotator: state.annotator,
    };
    setLabel(fd, m);
    // the overlay arrives as pixels (ov32, edited here) and as a bitmap the worker made of them
    // (drawn until the first edit: then ensureOvCanvas uploads the pixels to a canvas)
    fd.ovCanvas = null; fd.octx = null;
    fd.ovImg = new ImageData(m.ov, fd.W, fd.H);
    fd.ov32 = new Uint32Array(m.ov.buffer);
    fd.ovFlags = flags();
    const t2 = performance.now();
    let im;
    try { im = await image; } catch (e) { overlay.then((o) => o.overlay.close(), () => {}); throw e; }  // decoded meanwhile
    fd.bmp[kind] = im.bitmap;
    fd.ovBmp = (await overlay).overlay;
    window.zcut.loads.push({ index, worker: t1 - t0, main: t2 - t1, image: im.decoded, wait: performance.now() - t2,
                             ...m.timing });
    return fd;
  })();
  cache.set(index, p);
  p.catch(() => cache.delete(index));
  return p;
}

function bitmapFor(fd) {
  const kind = viewKind();
  if (fd.bmp[kind]) return fd.bmp[kind];
  if (!fd.bmpLoading) {
    fd.bmpLoading = call({ type: 'image', index: fd.index, kind }, [], imageWorker).then((m) => {
      fd.bmp[kind] = m.bitmap; fd.bmpLoading = null; requestDraw();
    }, (e) => { fd.bmpLoading = null; showError(String(e)); });
  }
  return fd.bmp.rgb || fd.bmp.height;
}

function evict(center) {
  for (const [i, p] of cache) {
    if (Math.abs(i - center) <= CACHE_RADIUS) continue;
    p.then((fd) => {
      if (fd.dirty || fd.saving || state.cur === fd) return;
      cache.delete(i);
      for (const b of Object.values(fd.bmp)) b.close();
      if (fd.ovBmp) { fd.ovBmp.close(); fd.ovBmp = null; }
      if (fd.ovCanvas) fd.ovCanvas.width = fd.ovCanvas.height = 0;
    }, () => {});
  }
}

// ------------------------------------------------------------------ overlay + drawing
const canvas = $('canvas'), ctx = canvas.getContext('2d');

function ensureOvCanvas(fd) {
  if (fd.ovCanvas) return;
  fd.ovCanvas = document.createElement('canvas');
  fd.ovCanvas.width = fd.W; fd.ovCanvas.height = fd.H;
  fd.octx = fd.ovCanvas.getContext('2d');
  fd.octx.putImageData(fd.ovImg, 0, 0);
  if (fd.ovBmp) { fd.ovBmp.close(); fd.ovBmp = null; }
}

function renderOverlay(x0 = 0, y0 = 0, x1 = null, y1 = null) {
  const fd = state.cur; if (!fd) return;
  ensureOvCanvas(fd);
  const W = fd.W, ov32 = fd.ov32;
  if (x1 === null && y1 === null && x0 === 0 && y0 === 0) fd.ovFlags = flags();
  x1 = x1 === null ? fd.W : Math.min(x1, fd.W); y1 = y1 === null ? fd.H : Math.min(y1, fd.H);
  x0 = Math.max(0, x0 | 0); y0 = Math.max(0, y0 | 0); x1 = Math.ceil(x1); y1 = Math.ceil(y1);
  if (x1 <= x0 || y1 <= y0) return;
  const { L, R, valid, zIds, sIds } = fd;
  const sL = state.showL, sZ = state.showZ, sS = state.showS, hasR = fd.hasR;
  for (let y = y0; y < y1; y++) {
    let i = y * W + x0;
    for (let x = x0; x < x1; x++, i++) {
      let c = 0;
      if (sL && L[i]) c = COL_L;
      else {
        const z = sZ && zIds[i] !== 0, s = sS && sIds[i] !== 0;
        if (z) c = s ? COL_ZS : COL_Z; else if (s) c = COL_S;
        else if (hasR && valid[i] && !R[i]) c = COL_UNREV;
      }
      ov32[i] = c;
    }
  }
  fd.octx.putImageData(fd.ovImg, 0, 0, x0, y0, x1 - x0, y1 - y0);
}

let drawQueued = false;
function requestDraw() {
  if (drawQueued) return;
  drawQueued = true;
  requestAnimationFrame(() => { drawQueued = false; draw(); });
}

function draw() {
  const fd = state.cur;
  const dpr = window.devicePixelRatio || 1;
  const cw = Math.round(canvas.clientWidth * dpr), ch = Math.round(canvas.clientHeight * dpr);
  if (canvas.width !== cw || canvas.height !== ch) { canvas.width = cw; canvas.height = ch; }
  ctx.setTransform(1, 0, 0, 1, 0, 0);
  ctx.fillStyle = '#111'; ctx.fillRect(0, 0, cw, ch);
  if (!fd) return;
  const z = state.zoom * dpr;
  ctx.setTransform(z, 0, 0, z, state.px * dpr, state.py * dpr);
  ctx.imageSmoothingEnabled = state.zoom < 1;
  ctx.drawImage(bitmapFor(fd), 0, 0);
  ctx.imageSmoothingEnabled = false;
  ctx.drawImage(fd.ovCanvas || fd.ovBmp, 0, 0);
  // tool previews (image coordinates)
  ctx.lineWidth = 1.5 / state.zoom; ctx.strokeStyle = '#fff';
  if (drag && drag.kind === 'box') {
    ctx.strokeRect(drag.x0, drag.y0, drag.x - drag.x0, drag.y - drag.y0);
  } else if (drag && drag.kind === 'lasso' && drag.pts.length > 1) {
    ctx.beginPath(); ctx.moveTo(drag.pts[0][0], drag.pts[0][1]);
    for (const [x, y] of drag.pts) ctx.lineTo(x, y);
    ctx.stroke();
  }
  if (hover && ['brush', 'eraser', 'unreviewed'].includes(state.tool)) {
    ctx.beginPath(); ctx.arc(hover.x, hover.y, state.brush, 0, 2 * Math.PI); ctx.stroke();
  }
}

function fit() {
  const fd = state.cur; if (!fd) return;
  const vw = canvas.clientWidth, vh = canvas.clientHeight;
  state.zoom = Math.min(vw / fd.W, vh / fd.H);
  state.px = (vw - fd.W * state.zoom) / 2; state.py = (vh - fd.H * state.zoom) / 2;
  requestDraw();
}

// ------------------------------------------------------------------ navigation
let navToken = 0;
async function goTo(index, t0 = performance.now()) {
  if (index < 0 || (state.total && index >= state.total)) return;
  const my = ++navToken;
  if (state.cur) saveNow(state.cur);
  let fd;
  try { fd = await loadFrame(index); } catch (e) { showError(String(e)); return; }
  if (my !== navToken) return;
  const sameShape = state.cur && state.cur.W === fd.W && state.cur.H === fd.H;
  const dir = state.cur && index < state.cur.index ? -1 : 1;
  state.cur = fd;
  $('conflict').hidden = !fd.conflict;
  $('latest').textContent = fd.conflict || '';
  if (!sameFlags(fd.ovFlags, flags())) renderOverlay();
  if (!sameShape || !state.fitted) { fit(); state.fitted = true; }
  draw();
  updateInfo();
  requestAnimationFrame(() => {
    window.zcut.switchTimes.push(performance.now() - t0);
    window.zcut.shown = index;
  });
  history.replaceState(null, '', `?token=${encodeURIComponent(TOKEN)}#${index}`);
  evict(index);
  (async () => {  // prefetch the neighbours one at a time, the next one in the direction of travel first
    for (const d of [dir, -dir, 2 * dir, -2 * dir]) {
      const j = index + d;
      if (my !== navToken) return;
      if (j >= 0 && (!state.total || j < state.total)) { try { await loadFrame(j); } catch (e) { /* shown on use */ } }
    }
  })();
}

function updateInfo() {
  const fd = state.cur;
  if (fd) $('frameinfo').textContent = `frame ${fd.index} / ${Math.max(state.total - 1, 0)}  stamp ${fd.stamp}  ` +
    `z-cut ${fd.header.n_zcut} · SOR ${fd.header.n_sor} clusters  rev ${fd.rev}`;
  const reviewed = state.frames.filter((f) => f.reviewed).length;
  $('progress').textContent = `reviewed ${reviewed} / ${state.total}` + (state.done ? '' : ' (preparing…)');
  const ol = $('framelist');
  if (ol.children.length !== state.frames.length) {
    ol.innerHTML = '';
    for (const f of state.frames) {
      const li = document.createElement('li');
      li.textContent = `${f.stamp_ns}`;
      li.onclick = () => goTo(f.index);
      ol.appendChild(li);
    }
  }
  state.frames.forEach((f, k) => {
    const li = ol.children[k];
    li.classList.toggle('rev', !!f.reviewed);
    li.classList.toggle('cur', !!fd && f.index === fd.index);
  });
}

async function refreshFrames() {
  const r = await api(`/api/frames?annotator=${encodeURIComponent(state.annotator)}`);
  if (!r.ok) return;
  const j = await r.json();
  state.frames = j.frames; state.total = j.total; state.done = j.done;
  if (j.error) showError(`preparing frames stopped: ${j.error}`);
  updateInfo();
  if (!state.done) setTimeout(refreshFrames, 1000);
}

function nextUnreviewed() {
  const start = state.cur ? state.cur.index : -1;
  const f = state.frames.find((g) => g.index > start && !g.reviewed) || state.frames.find((g) => !g.reviewed);
  if (f) goTo(f.index);
}

// ------------------------------------------------------------------ editing
function ensureReviewed(fd) {
  if (!fd.hasR) { fd.R.set(fd.valid); fd.hasR = true; return true; }
  return false;
}

let action = null;  // {x0, y0, x1, y1} dirty box of the running edit
function beginAction(fd) {
  action = { x0: Infinity, y0: Infinity, x1: -Infinity, y1: -Infinity, full: ensureReviewed(fd) };
}
function touch(x0, y0, x1, y1) {
  action.x0 = Math.min(action.x0, x0); action.y0 = Math.min(action.y0, y0);
  action.x1 = Math.max(action.x1, x1); action.y1 = Math.max(action.y1, y1);
}
function endAction(fd) {
  const a = action; action = null;
  if (!a) return;
  const W = fd.W;
  let x0 = 0, y0 = 0, x1 = fd.W, y1 = fd.H;
  if (!a.full) {
    if (a.x1 < a.x0) return;
    x0 = Math.max(0, Math.floor(a.x0)); y0 = Math.max(0, Math.floor(a.y0));
    x1 = Math.min(fd.W, Math.ceil(a.x1)); y1 = Math.min(fd.H, Math.ceil(a.y1));
  }
  let rec;
  if (a.full) {
    // the first edit of a frame marks every valid pixel reviewed: keep whole snapshots, not diffs
    rec = { full: true, oL: fd.committedL, oR: fd.committedR, nL: fd.L.slice(), nR: fd.R.slice(), hadR: false };
    fd.committedL = fd.L.slice(); fd.committedR = fd.R.slice();
  } else {
    const idx = [], oL = [], oR = [];
    for (let y = y0; y < y1; y++) for (let i = y * W + x0, e = y * W + x1; i < e; i++) {
      if (fd.L[i] !== fd.committedL[i] || fd.R[i] !== fd.committedR[i]) {
        idx.push(i); oL.push(fd.committedL[i]); oR.push(fd.committedR[i]);
        fd.committedL[i] = fd.L[i]; fd.committedR[i] = fd.R[i];
      }
    }
    if (!idx.length) return;
    rec = { idx: Int32Array.from(idx), oL: Uint8Array.from(oL), oR: Uint8Array.from(oR), hadR: true };
    rec.nL = Uint8Array.from(rec.idx, (i) => fd.L[i]); rec.nR = Uint8Array.from(rec.idx, (i) => fd.R[i]);
  }
  fd.undo.push(rec); if (fd.undo.length > 200) fd.undo.shift();
  fd.redo = [];
  renderOverlay(a.full ? 0 : x0, a.full ? 0 : y0, a.full ? null : x1, a.full ? null : y1);
  requestDraw();
  scheduleSave(fd);
}

function applyRecord(fd, rec, forward) {
  const vL = forward ? rec.nL : rec.oL, vR = forward ? rec.nR : rec.oR;
  if (rec.full) {
    fd.L.set(vL); fd.R.set(vR); fd.committedL.set(vL); fd.committedR.set(vR);
  } else for (let k = 0; k < rec.idx.length; k++) {
    const i = rec.idx[k];
    fd.L[i] = fd.committedL[i] = vL[k]; fd.R[i] = fd.committedR[i] = vR[k];
  }
  fd.hasR = forward ? true : rec.hadR;
  renderOverlay(); requestDraw(); scheduleSave(fd);
}
function undo() { const fd = state.cur; if (fd && fd.undo.length) { const r = fd.undo.pop(); applyRecord(fd, r, false); fd.redo.push(r); } }
function redo() { const fd = state.cur; if (fd && fd.redo.length) { const r = fd.redo.pop(); applyRecord(fd, r, true); fd.undo.push(r); } }

function paintDisc(fd, cx, cy, r, mode) {
  const W = fd.W, H = fd.H;
  const x0 = Math.max(0, Math.floor(cx - r)), x1 = Math.min(W - 1, Math.ceil(cx + r));
  const y0 = Math.max(0, Math.floor(cy - r)), y1 = Math.min(H - 1, Math.ceil(cy + r));
  const r2 = r * r;
  for (let y = y0; y <= y1; y++) for (let x = x0; x <= x1; x++) {
    const dx = x + 0.5 - cx, dy = y + 0.5 - cy;
    if (dx * dx + dy * dy > r2) continue;
    setPixel(fd, y * W + x, mode);
  }
  touch(x0, y0, x1 + 1, y1 + 1);
  renderOverlay(x0, y0, x1 + 1, y1 + 1);
}
function setPixel(fd, i, mode) {
  if (!fd.valid[i]) return;
  if (mode === 'add') { fd.L[i] = 1; fd.R[i] = 1; }
  else if (mode === 'erase') { fd.L[i] = 0; }
  else if (mode === 'unreview') { fd.L[i] = 0; fd.R[i] = 0; }
}
function paintLine(fd, a, b, mode) {
  const d = Math.hypot(b.x - a.x, b.y - a.y), step = Math.max(1, state.brush / 3);
  const n = Math.max(1, Math.ceil(d / step));
  for (let k = 1; k <= n; k++) paintDisc(fd, a.x + (b.x - a.x) * k / n, a.y + (b.y - a.y) * k / n, state.brush, mode);
}

function toggleCluster(fd, x, y, preferSor) {
  x = Math.floor(x); y = Math.floor(y);
  if (x < 0 || y < 0 || x >= fd.W || y >= fd.H) return false;
  const i = y * fd.W + x;
  const order = preferSor ? [[fd.sIds, state.showS], [fd.zIds, state.showZ]] : [[fd.zIds, state.showZ], [fd.sIds, state.showS]];
  let ids = null, id = 0;
  for (const [arr, shown] of order) if (shown && arr[i] !== 0) { ids = arr; id = arr[i]; break; }
  if (!ids) return false;
  beginAction(fd);
  let n = 0, inL = 0;
  const members = [];
  for (let k = 0; k < ids.length; k++) if (ids[k] === id) { members.push(k); n++; if (fd.L[k]) inL++; }
  const accept = inL * 2 < n;
  let x0 = fd.W, y0 = fd.H, x1 = 0, y1 = 0;
  for (const k of members) {
    setPixel(fd, k, accept ? 'add' : 'erase');
    const px = k % fd.W, py = (k / fd.W) | 0;
    if (px < x0) x0 = px; if (px > x1) x1 = px; if (py < y0) y0 = py; if (py > y1) y1 = py;
  }
  touch(x0, y0, x1 + 1, y1 + 1);
  endAction(fd);
  return true;
}

function acceptAll(ids) {  // every candidate pixel of one filter becomes an outlier (one undo step)
  const fd = state.cur; if (!fd || !ids) return;
  beginAction(fd);
  let x0 = fd.W, y0 = fd.H, x1 = 0, y1 = 0;
  for (let i = 0; i < ids.length; i++) {
    if (ids[i] === 0) continue;
    setPixel(fd, i, 'add');
    const x = i % fd.W, y = (i / fd.W) | 0;
    if (x < x0) x0 = x; if (x > x1) x1 = x; if (y < y0) y0 = y; if (y > y1) y1 = y;
  }
  touch(x0, y0, x1 + 1, y1 + 1);
  endAction(fd);
}

function fillPolygon(fd, pts, mode) {
  let x0 = Infinity, y0 = Infinity, x1 = -Infinity, y1 = -Infinity;
  for (const [x, y] of pts) { x0 = Math.min(x0, x); y0 = Math.min(y0, y); x1 = Math.max(x1, x); y1 = Math.max(y1, y); }
  x0 = Math.max(0, Math.floor(x0)); y0 = Math.max(0, Math.floor(y0));
  x1 = Math.min(fd.W, Math.ceil(x1)); y1 = Math.min(fd.H, Math.ceil(y1));
  const w = x1 - x0, h = y1 - y0;
  if (w <= 0 || h <= 0) return;
  const c = new OffscreenCanvas(w, h), g = c.getContext('2d');
  g.fillStyle = '#fff'; g.beginPath();
  g.moveTo(pts[0][0] - x0, pts[0][1] - y0);
  for (const [x, y] of pts) g.lineTo(x - x0, y - y0);
  g.closePath(); g.fill();
  const a = g.getImageData(0, 0, w, h).data;
  for (let yy = 0; yy < h; yy++) for (let xx = 0; xx < w; xx++) {
    // pixel centres inside the polygon (alpha ≥ 50 %)
    if (a[(yy * w + xx) * 4 + 3] >= 128) setPixel(fd, (yy + y0) * fd.W + xx + x0, mode);
  }
  touch(x0, y0, x1, y1);
}

function markReviewedAndNext() {
  const fd = state.cur; if (!fd) return;
  beginAction(fd); endAction(fd);
  if (!fd.dirty && fd.rev === 0) scheduleSave(fd);
  saveNow(fd);
  if (fd.index + 1 < state.total) goTo(fd.index + 1);
}

// ------------------------------------------------------------------ saving
function setSaveState(text, cls) { const s = $('savestate'); s.textContent = text; s.className = 'state ' + cls; }
function showError(msg) { window.zcut.errors.push(msg); setSaveState(msg, 'error'); }

function scheduleSave(fd) {
  fd.dirty = true;
  setSaveState('unsaved', 'saving');
  clearTimeout(fd.saveTimer);
  fd.saveTimer = setTimeout(() => saveNow(fd), 300);
}

async function saveNow(fd) {
  clearTimeout(fd.saveTimer);
  if (!fd.dirty || fd.conflict) return;
  if (fd.saving) { fd.pendingSave = true; return; }
  fd.saving = true; fd.dirty = false;
  setSaveState('saving…', 'saving');
  let retry = false;
  try {
    const L = fd.L.slice(), R = fd.R.slice();
    const packed = await call({ type: 'pack', L, R }, [L.buffer, R.buffer]);
    const body = JSON.stringify({ annotator: fd.annotator, base_revision: fd.rev, height: fd.H, width: fd.W,
                                  outliers: packed.outliers, reviewed: packed.reviewed });
    const resp = await api(`/api/frames/${fd.index}/label`, { method: 'PUT', headers: { 'Content-Type': 'application/json' }, body });
    if (resp.ok) {
      const j = await resp.json();
      fd.rev = j.revision;
      window.zcut.acks.push({ index: fd.index, revision: j.revision, n_outliers: j.n_outliers, annotator: j.annotator });
      const f = state.frames.find((g) => g.index === fd.index);
      if (f) { f.reviewed = j.n_reviewed > 0; f.revision = j.revision; f.n_outliers = j.n_outliers; }
      setSaveState(`saved (frame ${fd.index} rev ${j.revision})`, 'saved');
      updateInfo();
    } else if (resp.status === 409) {
      const j = await resp.json();
      fd.dirty = true; fd.conflict = j.latest;
      if (fd === state.cur) { $('latest').textContent = j.latest; $('conflict').hidden = false; }
      showError(`conflict on frame ${fd.index}`);
    } else {
      const t = await resp.text();
      fd.dirty = true;
      showError(`save failed (HTTP ${resp.status}): ${t.slice(0, 200)}`);
      retry = resp.status >= 500;
    }
  } catch (e) {
    fd.dirty = true; retry = true;
    showError(`save failed: ${e}`);
  } finally {
    fd.saving = false;
  }
  if (fd.pendingSave || (fd.dirty && retry)) {
    fd.pendingSave = false;
    if (retry) setTimeout(() => saveNow(fd), 2000); else saveNow(fd);
  }
}

async function resolveConflict(keepMine) {
  const fd = state.cur; if (!fd || !fd.conflict) return;
  $('conflict').hidden = true;
  if (keepMine) { fd.rev = fd.conflict; fd.conflict = 0; fd.dirty = true; saveNow(fd); }
  else { fd.conflict = 0; await loadLabel(fd); renderOverlay(); requestDraw(); updateInfo(); }
}

// ------------------------------------------------------------------ input
let drag = null, hover = null, spaceDown = false;
function toImage(e) {
  const r = canvas.getBoundingClientRect();
  return { x: (e.clientX - r.left - state.px) / state.zoom, y: (e.clientY - r.top - state.py) / state.zoom };
}
window.zcut.goTo = (i) => goTo(i);
window.zcut.overlayConsistent = () => {  // the worker's overlay of the frame equals the main thread's
  const fd = state.cur; if (!fd) return false;
  const before = fd.ov32.slice();
  renderOverlay();
  for (let i = 0; i < before.length; i++) if (before[i] !== fd.ov32[i]) return false;
  return true;
};
window.zcut.imageToClient = (x, y) => {
  const r = canvas.getBoundingClientRect();
  return { x: r.left + state.px + (x + 0.5) * state.zoom, y: r.top + state.py + (y + 0.5) * state.zoom };
};
window.zcut.state = () => {
  const fd = state.cur; if (!fd) return null;
  let nL = 0, nR = 0;
  for (let i = 0; i < fd.L.length; i++) { nL += fd.L[i]; nR += fd.R[i]; }
  return { index: fd.index, rev: fd.rev, dirty: fd.dirty, saving: fd.saving, conflict: fd.conflict, nL, nR,
           W: fd.W, H: fd.H, tool: state.tool, zoom: state.zoom, annotator: state.annotator,
           brush: state.brush, view: state.showH ? 'height' : 'rgb', progress: $('progress').textContent };
};

canvas.addEventListener('contextmenu', (e) => e.preventDefault());
canvas.addEventListener('pointerdown', (e) => {
  const fd = state.cur; if (!fd) return;
  canvas.setPointerCapture(e.pointerId);
  const p = toImage(e);
  if (e.button === 2 || e.button === 1 || spaceDown) {
    drag = { kind: 'pan', sx: e.clientX, sy: e.clientY, px: state.px, py: state.py };
    return;
  }
  if (e.button !== 0) return;
  const t = state.tool;
  if (t === 'select') { toggleCluster(fd, p.x, p.y, e.altKey); return; }
  if (t === 'brush' || t === 'eraser' || t === 'unreviewed') {
    const mode = t === 'brush' ? 'add' : t === 'eraser' ? 'erase' : 'unreview';
    beginAction(fd);
    paintDisc(fd, p.x, p.y, state.brush, mode);
    drag = { kind: 'paint', mode, last: p };
    requestDraw();
  } else if (t === 'box') {
    drag = { kind: 'box', x0: p.x, y0: p.y, x: p.x, y: p.y, erase: e.shiftKey };
  } else if (t === 'lasso') {
    drag = { kind: 'lasso', pts: [[p.x, p.y]], erase: e.shiftKey };
  }
});
canvas.addEventListener('pointermove', (e) => {
  const p = toImage(e);
  hover = p;
  const fd = state.cur;
  if (drag && fd) {
    if (drag.kind === 'pan') { state.px = drag.px + e.clientX - drag.sx; state.py = drag.py + e.clientY - drag.sy; }
    else if (drag.kind === 'paint') { paintLine(fd, drag.last, p, drag.mode); drag.last = p; }
    else if (drag.kind === 'box') { drag.x = p.x; drag.y = p.y; }
    else if (drag.kind === 'lasso') drag.pts.push([p.x, p.y]);
  }
  requestDraw();
});
canvas.addEventListener('pointerup', (e) => {
  const fd = state.cur, d = drag; drag = null;
  if (!d || !fd) return;
  if (d.kind === 'paint') endAction(fd);
  else if (d.kind === 'box') {
    const pts = [[d.x0, d.y0], [d.x, d.y0], [d.x, d.y], [d.x0, d.y]];
    beginAction(fd); fillPolygon(fd, pts, d.erase || e.shiftKey ? 'erase' : 'add'); endAction(fd);
  } else if (d.kind === 'lasso' && d.pts.length > 2) {
    beginAction(fd); fillPolygon(fd, d.pts, d.erase || e.shiftKey ? 'erase' : 'add'); endAction(fd);
  }
  requestDraw();
});
canvas.addEventListener('pointerleave', () => { hover = null; requestDraw(); });
canvas.addEventListener('wheel', (e) => {
  e.preventDefault();
  const r = canvas.getBoundingClientRect();
  const mx = e.clientX - r.left, my = e.clientY - r.top;
  const f = Math.exp(-e.deltaY * 0.0015), z = Math.min(64, Math.max(0.05, state.zoom * f));
  state.px = mx - (mx - state.px) * z / state.zoom; state.py = my - (my - state.py) * z / state.zoom;
  state.zoom = z;
  requestDraw();
}, { passive: false });

function setTool(t) {
  state.tool = t;
  for (const b of document.querySelectorAll('#tools button')) b.classList.toggle('active', b.dataset.tool === t);
  requestDraw();
}
function setBrush(v) {
  state.brush = Math.max(1, Math.min(80, v | 0));
  $('brushsize').value = state.brush; $('brushval').textContent = state.brush;
  requestDraw();
}
function toggle(key, box) {
  state[key] = !state[key]; $(box).checked = state[key];
  renderOverlay(); requestDraw();
}

window.addEventListener('keydown', (e) => {
  if (e.target instanceof HTMLInputElement && e.target.type === 'text') return;
  const k = e.key, fd = state.cur;
  const ctrl = e.ctrlKey || e.metaKey;
  const t0 = e.timeStamp || performance.now();
  if (k === ' ') { spaceDown = true; e.preventDefault(); return; }
  if (ctrl && (k === 'z' || k === 'Z')) { e.shiftKey ? redo() : undo(); e.preventDefault(); return; }
  if (ctrl && (k === 'y' || k === 'Y')) { redo(); e.preventDefault(); return; }
  if (ctrl) return;
  switch (k) {
    case 'ArrowRight': case 'PageDown': if (fd) goTo(fd.index + 1, t0); break;
    case 'ArrowLeft': case 'PageUp': if (fd) goTo(fd.index - 1, t0); break;
    case 'n': case 'N': nextUnreviewed(); break;
    case 'Enter': markReviewedAndNext(); break;
    case 'v': case 'V': setTool('select'); break;
    case 'b': case 'B': setTool('brush'); break;
    case 'e': case 'E': setTool('eraser'); break;
    case 'x': case 'X': setTool('box'); break;
    case 'l': case 'L': setTool('lasso'); break;
    case 'u': case 'U': setTool('unreviewed'); break;
    case '[': setBrush(state.brush - (state.brush > 10 ? 2 : 1)); break;
    case ']': setBrush(state.brush + (state.brush >= 10 ? 2 : 1)); break;
    case 'a': case 'A': acceptAll(e.altKey ? fd && fd.sIds : fd && fd.zIds); break;
    case 'z': undo(); break;
    case 'Z': redo(); break;
    case 'f': case 'F': case '0': fit(); break;
    case '1': toggle('showZ', 'showZ'); break;
    case '2': toggle('showS', 'showS'); break;
    case '3': toggle('showL', 'showL'); break;
    case 'h': case 'H': toggle('showH', 'showH'); break;
    default: return;
  }
  e.preventDefault();
});
window.addEventListener('keyup', (e) => { if (e.key === ' ') spaceDown = false; });
window.addEventListener('resize', () => requestDraw());
window.addEventListener('beforeunload', (e) => {
  for (const p of cache.values()) p.then((fd) => { if (fd.dirty) saveNow(fd); }, () => {});
  if (state.cur && (state.cur.dirty || state.cur.saving)) { e.preventDefault(); e.returnValue = ''; }
});

for (const b of document.querySelectorAll('#tools button')) b.onclick = () => setTool(b.dataset.tool);
$('brushsize').oninput = (e) => setBrush(+e.target.value);
for (const [key, box] of [['showZ', 'showZ'], ['showS', 'showS'], ['showL', 'showL'], ['showH', 'showH']]) {
  $(box).onchange = () => { state[key] = $(box).checked; renderOverlay(); requestDraw(); };
}
$('prev').onclick = () => state.cur && goTo(state.cur.index - 1);
$('next').onclick = () => state.cur && goTo(state.cur.index + 1);
$('done').onclick = markReviewedAndNext;
$('undo').onclick = undo; $('redo').onclick = redo;
$('reload').onclick = () => resolveConflict(false);
$('overwrite').onclick = () => resolveConflict(true);
$('annotator').value = state.annotator;
$('annotator').onchange = async (e) => {
  const name = e.target.value.trim();
  if (!name || name === state.annotator) { e.target.value = state.annotator; return; }
  for (const p of cache.values()) { try { const fd = await p; await saveNow(fd); } catch (err) { /* shown */ } }
  state.annotator = name; localStorage.setItem('zcut.annotator', name);
  for (const p of cache.values()) {
    try { const fd = await p; fd.annotator = name; await loadLabel(fd); } catch (err) { /* shown */ }
  }
  renderOverlay(); requestDraw(); await refreshFrames(); updateInfo();
};

// ------------------------------------------------------------------ start
(async () => {
  $('logname').textContent = BOOT.log;
  setTool('select'); setBrush(8);
  const s = await (await fetchOk('/api/session')).json();
  const notes = s.notes.concat((s.damage || []).map((d) => `data loss: ${d}`));
  if (notes.length) $('notes').textContent = notes.join('\n');
  await refreshFrames();
  const want = parseInt(location.hash.slice(1), 10);
  await goTo(Number.isFinite(want) ? want : 0);
  window.zcut.ready = true;
})().catch((e) => showError(String(e)));
