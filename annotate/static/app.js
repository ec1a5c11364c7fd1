// zcut labelling page. Vanilla JS + canvas (+ WebGL for the 3D view), no build step, nothing from the
// network: every file comes from this server.
// Data per frame: one binary bundle (valid mask, candidate cluster ids, the candidate table), a JPEG
// per view, the annotator's current label (outliers L, reviewed R), and exact points (x, y, z) fetched
// by 64 x 64 tiles for the cursor read-out, the profile and the 3D view. L ⊆ R ⊆ valid is kept by every
// tool; R grows only by decisions (accept, reject, paint) and by the explicit "reviewed" (Enter).
'use strict';

import { PointView } from './view3d.js';

const BOOT = JSON.parse(document.getElementById('boot').textContent);
const $ = (id) => document.getElementById(id);
const TILE = 64;
// tiles of one row per geometry request: the server's rectangle limit (routes.MAX_GEOMETRY_PX, in the boot data)
// over a tile's pixels, so that no request, however large the selection, exceeds it
const TILES_PER_REQUEST = Math.max(1, Math.floor((BOOT.max_geometry_px || TILE * TILE) / (TILE * TILE)));
const CLIENT = Array.from(crypto.getRandomValues(new Uint8Array(12)), (b) => b.toString(16).padStart(2, '0')).join('');
const KEEPALIVE_MAX = 60000;  // bytes a keepalive request may carry (browsers allow 64 KiB in flight)

// The token came in the URL: the server answered with a cookie; take the token out of the address
// bar and the history at once.
if (location.search) history.replaceState(null, '', '/' + location.hash);

async function fetchRetry(path, opts = {}, onWait = null) {  // 503 + Retry-After: ask again
  for (let tries = 0; ; tries++) {
    const r = await fetch(path, opts);
    if (r.status !== 503 || tries >= 600) return r;
    const wait = Math.min(5, Math.max(0.2, parseFloat(r.headers.get('Retry-After') || '1')));
    if (onWait) onWait(wait);
    await new Promise((res) => setTimeout(res, wait * 1000));
  }
}
async function fetchOk(path) {
  const r = await fetchRetry(path);
  if (!r.ok) throw new Error(`${path}: HTTP ${r.status} ${(await r.text()).slice(0, 200)}`);
  return r;
}

// ------------------------------------------------------------------ the workers (fetch, decode)
const worker = new Worker('/static/worker.js');
const imageWorker = new Worker('/static/worker.js');  // decodes JPEGs while the first unpacks masks
const pending = new Map();
let nextId = 1;
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
function expectReply() {  // a second reply to one message (the frame's overlay bitmap): [id, promise]
  const id = nextId++;
  return [id, new Promise((resolve, reject) => pending.set(id, { resolve, reject }))];
}

// ------------------------------------------------------------------ state
const state = {
  annotator: BOOT.annotator, mode: BOOT.mode,
  frames: [], order: [], orderBy: 'index', total: 0, done: false, target: null,
  cur: null, tool: 'select', brush: 8, sorMin: 5, sortKey: 'auto',
  showG: true, showZ: true, showS: false, showL: true, showH: false, showMini: true, riseMm: null, sessionLost: false,
  showOv: true, showF: true,  // O: the whole overlay (masks, outlines, markers) on / off; 4: the fits' outlines
  zoom: 1, px: 0, py: 0, fitted: false, sel: -1, profile: null, conflictView: 'mine', turbo: null,
};
const cache = new Map();  // index -> Promise<frame>
const loaded = new Map();  // index -> frame, once loaded (read synchronously when the page goes away)
const CACHE_RADIUS = 2;
window.zcut = { switchTimes: [], switchParts: [], acks: [], errors: [], loads: [], viewTimes: [], drawTimes: [], inputs: 0, pans: 0 };

const COL_L = rgba(255, 30, 60, 200), COL_Z = rgba(255, 170, 0, 150), COL_S = rgba(40, 150, 255, 140);
const COL_ZS = rgba(190, 90, 255, 160), COL_UNREV = rgba(0, 0, 0, 150), COL_DIFF = rgba(255, 0, 255, 220);
function rgba(r, g, b, a) { return ((a << 24) | (b << 16) | (g << 8) | r) >>> 0; }
const COL_G = rgba(0, 230, 230, 150), COL_GR = rgba(0, 120, 90, 110);  // review groups: undecided, reviewed
const COL = {  // candidate colours by source and state (markers, list, profile, 3D)
  g: '#00e6e6', z: '#ffaa00', s: '#2896ff', L: '#ff4da6', accepted: '#ff1e3c', rejected: '#5fd38d', sel: '#ffffff',
  u: '#ffeb00', f: '#aaff00',
};
const RGB = { accepted: [255, 30, 60], rejected: [95, 211, 141], g: [0, 230, 230], z: [255, 170, 0], s: [40, 150, 255],
              L: [255, 77, 166], u: [255, 235, 0] };

// ------------------------------------------------------------------ loading frames
function flags() { return { showL: state.showL, showZ: state.showZ, showS: state.showS, showG: state.showG, showF: state.showF, sorMin: state.sorMin }; }
function sameFlags(a, b) { return a && a.showL === b.showL && a.showZ === b.showZ && a.showS === b.showS && a.showG === b.showG && a.showF === b.showF && a.sorMin === b.sorMin; }
function viewKind() { return state.showH ? 'height' : 'rgb'; }

function setLabel(fd, lab) {
  fd.rev = lab.rev; fd.L = lab.L; fd.R = lab.R; fd.nR = lab.nR;
  fd.committedL = fd.L.slice(); fd.committedR = fd.R.slice();
  fd.undo = []; fd.redo = []; fd.dirty = false; fd.conflict = null;
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
      m = await call({ type: 'frame', index, flags: flags(), imageId });
    } catch (e) {
      pending.delete(imageId);
      image.then((im) => im.bitmap.close(), () => {});
      throw e;
    }
    const t1 = performance.now();
    const h = m.header;
    const fd = {
      index, stamp: h.stamp_ns, W: h.width, H: h.height, header: h, nValid: h.n_valid,
      valid: m.valid, zone: m.zone, zIds: m.zIds, sIds: m.sIds, sSize: m.sSize, bmp: {}, small: {},
      zStart: m.zStart, zPix: m.zPix, sStart: m.sStart, sPix: m.sPix, cand: m.cand, cols: h.candidate_columns,
      gIds: m.gIds, gStart: m.gStart, gPix: m.gPix, gTable: m.gTable, rise: m.rise,
      tiles: new Map(), saving: false, pendingSave: false, seq: 0, prop: null,
    };
    setLabel(fd, m);
    restorePending(fd);
    buildEntries(fd);
    fd.ovCanvas = null; fd.octx = null;
    fd.ovImg = new ImageData(m.ov, fd.W, fd.H);
    fd.ov32 = new Uint32Array(m.ov.buffer);
    fd.ovFlags = flags(); fd.ovShade = m.shade;
    const t2 = performance.now();
    let im;
    try { im = await image; } catch (e) { overlay.then((o) => o.overlay.close(), () => {}); throw e; }
    fd.bmp[kind] = im.bitmap; fd.small[kind] = im.small;
    fd.ovBmp = (await overlay).overlay;
    window.zcut.loads.push({ index, worker: t1 - t0, main: t2 - t1, image: im.decoded, wait: performance.now() - t2,
                             ...m.timing });
    loaded.set(index, fd);
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
      fd.bmp[kind] = m.bitmap; fd.small[kind] = m.small; fd.bmpLoading = null; requestDraw();
    }, (e) => { fd.bmpLoading = null; showError(String(e)); });
  }
  return fd.bmp.rgb || fd.bmp.height;
}

function evict(center) {
  const keep = new Set();
  const k = state.order.indexOf(center);
  for (let d = -CACHE_RADIUS; d <= CACHE_RADIUS; d++) if (k + d >= 0 && k + d < state.order.length) keep.add(state.order[k + d]);
  keep.add(center);
  for (const [i, p] of cache) {
    if (keep.has(i)) continue;
    p.then((fd) => {
      if (fd.dirty || fd.saving || fd.conflict || state.cur === fd) return;
      cache.delete(i); loaded.delete(i);
      for (const b of [...Object.values(fd.bmp), ...Object.values(fd.small)]) b.close();
      if (fd.ovBmp) { fd.ovBmp.close(); fd.ovBmp = null; }
      if (fd.ovCanvas) fd.ovCanvas.width = fd.ovCanvas.height = 0;
    }, () => {});
  }
}

// ------------------------------------------------------------------ candidates
// An entry (a review group, annotate/groups.py): {src: 'g' | 'L', id, n, x0, y0, x1, y1, cx, cy, gap, hmin,
// hmax, below, why, dets, methods, score, pix}; 'L': a component of the label no group covers (painted by hand)
function buildEntries(fd) {
  const h = fd.header, c = h.group_columns || [], nc = c.length, rows = nc ? fd.gTable.length / nc : 0;
  const col = Object.fromEntries(c.map((n, i) => [n, i]));
  const out = [];
  for (let r = 0; r < rows; r++) {
    const v = (name) => fd.gTable[r * nc + col[name]];
    const id = v('id'), src = h.group_sources[v('source')], dets = v('detectors'), meth = v('methods');
    const also = h.detectors.filter((d, i) => (dets >> i) & 1 && d !== src)
      .concat(h.methods.filter((m, i) => (meth >> i) & 1 && m !== src));
    const hmin = v('h_min_mm'), hmax = v('h_max_mm'), gap = v('gap_mm');
    out.push({ src: 'g', id, k: r, n: v('n'), x0: v('x0'), y0: v('y0'), x1: v('x1'), y1: v('y1'), cx: v('cx'), cy: v('cy'),
               gap, hmin, hmax, below: isNaN(gap) ? NaN : hmin - gap, source: src, also, score: v('score'), both: 0,
               pix: fd.gPix.subarray(fd.gStart[id], fd.gStart[id + 1]) });
  }
  fd.base = out.concat(fd.propEntries || [], fd.fitEntries || []);  // and the fits' proposals and fits (loadFits)
  fd.covered = new Uint8Array(fd.W * fd.H);  // pixels of the review groups
  for (const e of fd.base) for (const i of e.pix) fd.covered[i] = 1;
  fd.labelEntries = labelComponents(fd);
  refreshList(fd, false);
}

// Components of L that no listed candidate covers (painted by hand): listed as 'L' entries.
function labelComponents(fd) {
  const W = fd.W, H = fd.H, L = fd.L, covered = fd.covered, out = [];
  let seen = null;
  const stack = [];
  for (let i = 0; i < L.length; i++) {
    if (!L[i] || covered[i] || (seen && seen[i])) continue;
    if (!seen) seen = new Uint8Array(L.length);
    const pix = []; let x0 = W, y0 = H, x1 = 0, y1 = 0, sx = 0, sy = 0;
    stack.push(i); seen[i] = 1;
    while (stack.length) {
      const j = stack.pop(); pix.push(j);
      const x = j % W, y = (j / W) | 0;
      x0 = Math.min(x0, x); x1 = Math.max(x1, x); y0 = Math.min(y0, y); y1 = Math.max(y1, y); sx += x + 0.5; sy += y + 0.5;
      for (let dy = -1; dy <= 1; dy++) for (let dx = -1; dx <= 1; dx++) {
        const xx = x + dx, yy = y + dy;
        if (xx < 0 || yy < 0 || xx >= W || yy >= H) continue;
        const k = yy * W + xx;
        if (L[k] && !seen[k] && !covered[k]) { seen[k] = 1; stack.push(k); }
      }
    }
    out.push({ src: 'L', id: out.length + 1, n: pix.length, x0, y0, x1: x1 + 1, y1: y1 + 1, cx: sx / pix.length,
               cy: sy / pix.length, hmin: NaN, hmax: NaN, below: NaN, gap: NaN, both: 0, level: -1, pix: Int32Array.from(pix) });
    if (out.length >= 2000) break;
  }
  return out;
}

function entryState(fd, e) {
  let inL = 0, inR = 0;
  for (const i of e.pix) { inL += fd.L[i]; inR += fd.R[i]; }
  return 2 * inL >= e.n ? 'accepted' : 2 * inR >= e.n ? 'rejected' : 'undecided';
}

function propP(fd, e) {  // the assistant's outlier probability of a group (NaN without one)
  return e.src === 'g' && fd.prop && fd.prop.p.length > e.k ? fd.prop.p[e.k] : NaN;
}
function confidence(fd, e) { const p = propP(fd, e); return isNaN(p) ? NaN : Math.max(p, 1 - p); }
// confident and pre-filled: only when the server lets the page pre-fill (the model agrees with the labels on
// held-out frames at least as often as the gate asks), else a proposal is shown plain and Y takes nothing
function confident(fd, e) { return !!(fd.prop && fd.prop.prefill) && confidence(fd, e) >= fd.prop.confident; }
const SORTS = {
  auto: (a, b) => (state.cur && state.cur.prop && state.cur.prop.p.length ? SORTS.uncertainty(a, b) : SORTS.score(a, b)),
  uncertainty: (a, b) => {
    const ca = confidence(state.cur, a), cb = confidence(state.cur, b);
    return (isNaN(ca) ? 2 : ca) - (isNaN(cb) ? 2 : cb) || SORTS.score(a, b);
  },
  score: (a, b) => (b.score || 0) - (a.score || 0) || b.n - a.n,
  gap: (a, b) => (isNaN(b.gap) ? -Infinity : b.gap) - (isNaN(a.gap) ? -Infinity : a.gap),
  size: (a, b) => b.n - a.n,
  disagree: (a, b) => (a.both / a.n) - (b.both / b.n) || SORTS.gap(a, b),
  position: (a, b) => (a.cy - b.cy) || (a.cx - b.cx),
};

// The list: every z-cut cluster, SOR clusters of at least sorMin pixels that the z-cut does not
// mostly cover (those are decided with it), and the hand-painted components; sorted by sortKey.
function refreshList(fd, keepSel = true, render = true) {
  const selE = keepSel && state.cur === fd && state.sel >= 0 ? fd.entries[state.sel] : null;
  const list = fd.base.slice();
  list.push(...fd.labelEntries);
  // the fits' proposals first (farthest from every known surface first), then the fits (largest Err first)
  const rank = (e) => (e.src === 'u' ? 0 : e.src === 'f' ? 1 : 2);
  list.sort((a, b) => rank(a) - rank(b) || (rank(a) < 2 ? (b.score - a.score) : SORTS[state.sortKey](a, b)) ||
    (a.cy - b.cy) || (a.cx - b.cx));
  fd.entries = list;
  if (state.cur === fd) {
    state.sel = selE ? list.indexOf(selE) : -1;
    fd.states = list.map((e) => entryState(fd, e));
    if (render) renderList();
  }
}

// no surface was measured below the group (a hole, the bin's edge): the gap says what to judge by instead
const GAP_UNKNOWN = 'gap unknown: no surface below — judge by the 3D view / profile';
function gapText(gap) {  // a gap to the surface: above (toward the camera) or below it
  if (isNaN(gap)) return 'no surface: 3D/profile';
  return gap >= 0 ? `${gap.toFixed(1)} mm up` : `${(-gap).toFixed(1)} mm down`;
}
// What the header and the panel count, one definition: the frame's review groups, those decided (at least
// half of their pixels labelled outlier or reviewed), and the painted components no group covers.
function groupCounts(fd) {
  const st = fd.states || [], ent = fd.entries || [];
  let groups = 0, decided = 0, painted = 0;
  ent.forEach((e, k) => {
    if (e.src === 'f' || e.src === 'u') return;  // the fits' own, counted by fitCounts
    if (e.src !== 'g') { painted++; return; }
    groups++;
    if (st[k] && st[k] !== 'undecided') decided++;
  });
  if (!ent.length) groups = fd.header.n_groups;
  return { groups, decided, painted };
}
function fitCounts(fd) {  // the fits' proposals (decided as groups are) and the fits (rejected)
  const st = fd.states || [], ent = fd.entries || [];
  let props = 0, decided = 0;
  ent.forEach((e, k) => { if (e.src === 'u') { props++; if (st[k] && st[k] !== 'undecided') decided++; } });
  return { fits: (fd.fitEntries || []).length, rejected: (fd.fitEntries || []).filter((e) => e.rejected).length, props, decided };
}
// said where the counts are shown (their title): what "decided" counts, here and on the server alike
const COUNTS_TITLE = 'a review group (or a proposal) is decided when at least half of its pixels are reviewed, by any ' +
  'decision: accepting the proposals decides the groups whose pixels they mostly cover';
function countsText(fd) {
  const c = groupCounts(fd), f = fitCounts(fd);
  return `${c.groups} groups · ${c.decided} decided` + (c.painted ? ` · ${c.painted} painted` : '') +
    (f.fits ? ` · ${f.fits} fits${f.rejected ? ` (${f.rejected} rejected)` : ''} · ${f.props} proposals, ${f.decided} decided` : '');
}
function stText(e, st) {  // a row's decision column
  return e.src === 'f' && e.rejected ? 'fit rejected' : st === 'accepted' ? 'outlier' : st === 'rejected' ? 'not outlier' : '·';
}
function rowClass(e, k, st) { return `cand ${st}${k === state.sel ? ' sel' : ''}${e.rejected ? ' fitrej' : ''}`; }
// The list's sections (only when the fits add their own): a head row each, with its counts; a click on it
// selects the section's next undecided entry (J does that for the whole list).
const SECTION = { u: 'u', f: 'f', g: 'g', L: 'g' };
function sectionText(fd, sec) {
  if (sec === 'u') { const f = fitCounts(fd); return `proposals: ${f.props} · ${f.decided} decided · ${f.props - f.decided} undecided`; }
  if (sec === 'f') { const f = fitCounts(fd); return `fits: ${f.fits}${f.rejected ? ` · ${f.rejected} rejected` : ''} (judged by looking; K rejects)`; }
  const c = groupCounts(fd);
  return `review groups: ${c.groups} · ${c.decided} decided · ${c.groups - c.decided} undecided` + (c.painted ? ` · ${c.painted} painted` : '');
}
function sameList(a, b) {
  if (!a || !b || a.length !== b.length) return false;
  for (let k = 0; k < a.length; k++) if (a[k] !== b[k]) return false;
  return true;
}
// Every entry has its row (thousands on a ray-traced frame: the rows are built once per list and only their
// state and selection are updated on a decision; the browser lays out only the rows in view).
function renderList() {
  const fd = state.cur, box = $('candlist');
  if (!fd) { box.innerHTML = ''; box.built = null; return; }
  const states = fd.states;
  $('candcount').textContent = countsText(fd); $('candcount').title = COUNTS_TITLE;
  const b = box.built;
  if (b && b.fd === fd && b.prop === fd.prop && b.sort === state.sortKey && sameList(b.entries, fd.entries)) {
    fd.entries.forEach((e, k) => {  // the same rows: their state and selection
      const row = b.rows[k], cls = rowClass(e, k, states[k]);
      if (row.className !== cls) { row.className = cls; row.querySelector('.st').textContent = stText(e, states[k]); }
    });
    for (const [sec, el] of b.heads) el.firstChild.textContent = sectionText(fd, sec);
  } else {
    const frag = document.createDocumentFragment(), rows = [], heads = new Map();
    const sections = new Set(fd.entries.map((e) => SECTION[e.src] || 'g')).size > 1;
    fd.entries.forEach((e, k) => {
      const sec = SECTION[e.src] || 'g';
      if (sections && !heads.has(sec)) {
        const h = document.createElement('div');
        h.className = 'sect'; h.dataset.sec = sec;
        h.innerHTML = '<span></span><span class="jump">next ▸</span>';
        h.firstChild.textContent = sectionText(fd, sec);
        h.title = 'click: the next undecided entry of this section (J: of the whole list)';
        h.onclick = () => { window.zcut.inputs++; jumpUndecided(1, sec); };
        heads.set(sec, h); frag.appendChild(h);
      }
      const row = listRow(fd, e, k, states[k]);
      rows.push(row); frag.appendChild(row);
    });
    const head = document.createElement('div');
    head.className = 'cand head';
    head.innerHTML = '<span>why (detector)</span><span>size</span><span>gap to surface</span><span title="the assistant: outlier or inlier, confidence">assist.</span><span>decision</span>';
    box.replaceChildren(head, frag);
    box.built = { fd, prop: fd.prop, sort: state.sortKey, entries: fd.entries.slice(), rows, heads };
  }
  const selRow = state.sel >= 0 ? box.built.rows[state.sel] : null;
  if (selRow) selRow.scrollIntoView({ block: 'nearest' });
  renderBulkHint(fd);
  updateInfo();  // the header and the frame list count what the panel counts
}
function listRow(fd, e, k, st) {
  if (e.src === 'f' || e.src === 'u') return fitRow(fd, e, k, st);
  const row = document.createElement('div');
  row.className = rowClass(e, k, st);
  row.dataset.k = k;
  const p = propP(fd, e), conf = confident(fd, e);
  const prop = isNaN(p) ? '' : `${p >= 0.5 ? 'out' : 'in'} ${Math.round(100 * Math.max(p, 1 - p))} %`;
  const why = e.src === 'L' ? 'painted' : e.source + (e.also.length ? ` +${e.also.join(',')}` : '');
  row.title = e.src === 'L' ? 'labelled by hand, no group covers it' :
    `${e.source}: ${e.n} px, median gap to the local surface ${isNaN(e.gap) ? 'unknown (no surface below): judge by the 3D view / profile' : e.gap >= 0 ? e.gap.toFixed(2) + ' mm above it' : (-e.gap).toFixed(2) + ' mm below it'}` + (e.also.length ? `; also flagged by ${e.also.join(', ')}` : '');
  row.innerHTML = `<span class="src ${e.src}">${why}</span><span>${e.n} px</span>` +
    `<span class="gap${isNaN(e.gap) && e.src === 'g' ? ' unknown' : ''}"${isNaN(e.gap) && e.src === 'g' ? ` title="${GAP_UNKNOWN}"` : ''}>${e.src === 'g' ? gapText(e.gap) : ''}</span>` +
    `<span class="agree${conf ? ' conf' : ''}">${prop}</span><span class="st">${stText(e, st)}</span>`;
  row.onclick = () => { window.zcut.inputs++; select(+row.dataset.k, { zoom: true }); };
  return row;
}
// J / Shift+J: the next / previous undecided entry of the list (of one section: a click on its head)
function jumpUndecided(d, sec = null) {
  const fd = state.cur; if (!fd || !fd.entries.length) return;
  const n = fd.entries.length;
  for (let s = 1; s <= n; s++) {
    const k = ((state.sel < 0 ? (d > 0 ? -1 : 0) : state.sel) + d * s + 2 * n) % n, e = fd.entries[k];
    if (e.src === 'f' || (sec && (SECTION[e.src] || 'g') !== sec)) continue;
    if (fd.states[k] === 'undecided') { select(k, { zoom: true }); return; }
  }
  setSaveState(sec ? 'nothing undecided left in this section' : 'nothing undecided left in the list', 'saved');
}

function fitRow(fd, e, k, st) {  // a fit ('f') or a proposal of the fits ('u') in the list
  const row = document.createElement('div');
  row.className = rowClass(e, k, st);
  row.dataset.k = k;
  const k3 = fd.fits ? fd.fits.header.k : 3;
  if (e.src === 'f') {
    row.title = `fitted instance #${e.id}: explains ${e.n} px within ${k3} × Err; residual Err ${e.err.toFixed(3)} mm, ` +
      `${Math.round(100 * e.support)} % of its visible surface supported` + (e.rejected ? `; rejected: ${e.proposed} of its ` +
      `px proposed again, the others lie within ${k3} × Err of another known surface (K takes it back)` : '; K rejects it');
    row.innerHTML = `<span class="src f">fit #${e.id}${e.seeded ? ' (seed)' : ''}</span><span>${e.n} px</span><span class="err">Err ${e.err.toFixed(2)} mm</span>` +
      `<span>${Math.round(100 * e.support)} %</span><span class="st">${stText(e, st)}</span>`;
  } else {
    const from = e.fromFit >= 0 ? `fit #${e.fromFit + 1} rej.` : 'unexplained';
    row.title = (e.fromFit >= 0 ? `${e.n} px of rejected fit #${e.fromFit + 1} farther than ${k3} × Err from every surface left` :
      `${e.n} px farther than ${k3} × Err from every known surface`) + (isNaN(e.dist) ? '' :
      `: median distance ${e.dist.toFixed(2)} mm (largest ${e.distMax.toFixed(2)} mm, Err ${e.err.toFixed(2)} mm)`);
    row.innerHTML = `<span class="src u">${from}</span><span>${e.n} px</span>` +
      `<span class="dist">${isNaN(e.dist) ? 'fit rejected' : `${e.dist.toFixed(1)} mm off`}</span><span></span>` +
      `<span class="st">${stText(e, st)}</span>`;
  }
  row.onclick = () => { window.zcut.inputs++; select(+row.dataset.k, { zoom: true }); };
  return row;
}

// What the bulk keys will do, said before they do it.
function proposalPlan(fd) {
  const out = [], inl = [];
  if (!fd.prop || !fd.prop.p.length) return { out, inl };
  fd.entries.forEach((e, k) => {
    if (e.src !== 'g' || fd.states[k] !== 'undecided' || !confident(fd, e)) return;
    (propP(fd, e) >= 0.5 ? out : inl).push(e);
  });
  return { out, inl };
}
function renderBulkHint(fd) {
  const und = fd.entries.filter((e, k) => (e.src === 'g' || e.src === 'u') && fd.states[k] === 'undecided').length;
  const px = fd.entries.filter((e, k) => (e.src === 'g' || e.src === 'u') && fd.states[k] === 'undecided').reduce((a, e) => a + e.n, 0);
  const parts = [`Shift+A accepts the ${und} undecided groups of this list (${px} px; not the z-cut or SOR overlays), Shift+R rejects them.`];
  const uu = fd.entries.filter((e, k) => e.src === 'u' && fd.states[k] === 'undecided');
  // first, where the one line shows it at 1366 x 768 (the rest is in the title)
  if (uu.length) parts.unshift(`Shift+U accepts the ${uu.length} proposals (${uu.reduce((a, e) => a + e.n, 0)} px).`);
  const pr = fd.prop;
  if (pr && pr.p.length) {
    const { out, inl } = proposalPlan(fd);
    if (pr.prefill) parts.push(`Y takes the assistant's ${out.length + inl.length} confident proposals (${out.length} outlier, ${inl.length} not).`);
    else parts.push(`Y does nothing: ${pr.why_not || 'no confident proposals'}.`);
  }
  $('bulkhint').textContent = $('bulkhint').title = parts.join(' ');
  const a = $('assistinfo');
  if (a) a.textContent = a.title = heldText(fd) || (pr ? pr.message + (pr.why_not && pr.model ? ` — ${pr.why_not}` : '') : 'assistant: …');
}

function select(k, { zoom = true, t0 = performance.now() } = {}) {
  const fd = state.cur; if (!fd) return;
  if (k < 0 || k >= fd.entries.length) { state.sel = -1; renderList(); requestDraw(); return; }
  state.sel = k;
  const e = fd.entries[k];
  if (zoom) zoomTo(e);
  state.profile = defaultProfile(fd, e);
  renderList();
  requestDraw();
  showViews(fd, e, t0);
  prefetchNeighbourhoods(fd, k);
}

function nextUndecided(fd, from) {
  const n = fd.entries.length;
  for (let d = 1; d <= n; d++) {
    const k = (from + d + n) % n;
    if (fd.entries[k].src === 'f') continue;  // a fit is judged by looking: K rejects a wrong one, Enter keeps the rest
    if (entryState(fd, fd.entries[k]) === 'undecided') return k;
  }
  return -1;
}

function decide(accept, t0) {
  const fd = state.cur; if (!fd || state.sel < 0) return;
  const e = fd.entries[state.sel];
  beginAction(fd);
  for (const i of e.pix) setPixel(fd, i, accept ? 'add' : 'erase');
  touch(e.x0, e.y0, e.x1, e.y1);
  endAction(fd);
  const k = nextUndecided(fd, state.sel);
  if (k >= 0) select(k, { zoom: true, t0 });
  else { state.sel = -1; renderList(); requestDraw(); setSaveState('every candidate decided: Enter marks the frame reviewed', 'saved'); }
}

function acceptProposals() {  // Y: the assistant's confident proposals of the undecided groups (one undo step)
  const fd = state.cur; if (!fd || !fd.prop) return;
  if (!fd.prop.prefill) { setSaveState(`nothing taken: ${fd.prop.why_not || 'no model yet'}`, 'error'); return; }
  const { out, inl } = proposalPlan(fd);
  if (!out.length && !inl.length) { setSaveState('no confident proposal left on this frame', 'saved'); return; }
  beginAction(fd);
  for (const [list, accept] of [[out, true], [inl, false]]) for (const e of list) fillEntry(fd, e, accept);
  endAction(fd);
  setSaveState(`took ${out.length + inl.length} proposals (${out.length} outlier, ${inl.length} not)`, 'saved');
  const k = nextUndecided(fd, -1);
  if (k >= 0) select(k, { zoom: true }); else { state.sel = -1; renderList(); requestDraw(); }
}

function decideAll(accept, proposalsOnly = false) {  // every undecided listed group, or proposal (one undo step)
  const fd = state.cur; if (!fd) return;
  beginAction(fd);
  fd.entries.forEach((e) => {
    if ((e.src !== 'u' && (proposalsOnly || e.src !== 'g')) || entryState(fd, e) !== 'undecided') return;
    fillEntry(fd, e, accept);
  });
  endAction(fd);
}
// A bulk decision (Shift+A, Shift+R, Shift+U, Y) fills what no decision reached yet: the pixels another entry
// decided (a proposal taken as outliers inside a group left undecided) keep that decision (setPixel's 'fill' modes).
function fillEntry(fd, e, accept) {
  for (const i of e.pix) setPixel(fd, i, accept ? 'fill-add' : 'fill-erase');
  touch(e.x0, e.y0, e.x1, e.y1);
}

// ------------------------------------------------------------------ geometry tiles (exact points)
function tileKey(tx, ty) { return ty * 100000 + tx; }
function ensureTiles(fd, x0, y0, x1, y1) {  // Promise: every 64 x 64 tile touching the rectangle loaded
  x0 = Math.max(0, Math.floor(x0)); y0 = Math.max(0, Math.floor(y0));
  x1 = Math.min(fd.W, Math.ceil(x1)); y1 = Math.min(fd.H, Math.ceil(y1));
  const waits = [], missing = [];
  for (let ty = Math.floor(y0 / TILE); ty * TILE < y1; ty++) for (let tx = Math.floor(x0 / TILE); tx * TILE < x1; tx++) {
    const t = fd.tiles.get(tileKey(tx, ty));
    if (t instanceof Promise) waits.push(t); else if (!t) missing.push([tx, ty]);
  }
  if (missing.length) {
    // one request per run of missing tiles of a row (at most TILES_PER_REQUEST of them)
    const rows = new Map();
    for (const [tx, ty] of missing) { if (!rows.has(ty)) rows.set(ty, []); rows.get(ty).push(tx); }
    for (const [ty, txs] of rows) {
      txs.sort((a, b) => a - b);
      for (let a = 0; a < txs.length;) {  // a run of consecutive missing tiles, cut at TILES_PER_REQUEST
        let b = a + 1;
        while (b < txs.length && b - a < TILES_PER_REQUEST && txs[b] === txs[b - 1] + 1) b++;
        const tA = txs[a], tB = txs[b - 1];
        a = b;
        const p = fetchTiles(fd, tA, tB, ty);
        for (let tx = tA; tx <= tB; tx++) if (!fd.tiles.get(tileKey(tx, ty))) fd.tiles.set(tileKey(tx, ty), p);
        waits.push(p);
      }
    }
  }
  return Promise.all(waits);
}
async function fetchTiles(fd, tA, tB, ty) {
  const x0 = tA * TILE, x1 = Math.min(fd.W, (tB + 1) * TILE), y0 = ty * TILE, y1 = Math.min(fd.H, (ty + 1) * TILE);
  const r = await fetchOk(`/api/frames/${fd.index}/geometry?x0=${x0}&y0=${y0}&x1=${x1}&y1=${y1}`);
  const buf = await r.arrayBuffer();
  const n = new DataView(buf).getUint32(0, true);
  const head = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, 4, n)));
  const w = head.width, h = head.height, planes = new Float32Array(buf.slice(4 + n));
  for (let tx = tA; tx <= tB; tx++) {
    const t = new Float32Array(3 * TILE * TILE).fill(NaN);
    for (let c = 0; c < 3; c++) for (let yy = 0; yy < h; yy++) for (let xx = 0; xx < TILE; xx++) {
      const gx = tx * TILE + xx - x0;
      if (gx >= w) break;
      t[c * TILE * TILE + yy * TILE + xx] = planes[c * w * h + yy * w + gx];
    }
    fd.tiles.set(tileKey(tx, ty), t);
  }
}
function point(fd, x, y) {  // [x, y, z] metres of pixel (x, y), or null (not loaded / no point)
  const t = fd.tiles.get(tileKey(Math.floor(x / TILE), Math.floor(y / TILE)));
  if (!(t instanceof Float32Array)) return null;
  const k = (y % TILE) * TILE + (x % TILE), X = t[k];
  if (Number.isNaN(X)) return null;
  return [X, t[TILE * TILE + k], t[2 * TILE * TILE + k]];
}

function neighbourhood(fd, e) {  // square around the cluster: 3 x its size, 48..128 px
  const side = Math.min(128, Math.max(48, 3 * Math.max(e.x1 - e.x0, e.y1 - e.y0)));
  const cx = (e.x0 + e.x1) / 2, cy = (e.y0 + e.y1) / 2;
  const x0 = Math.max(0, Math.round(cx - side / 2)), y0 = Math.max(0, Math.round(cy - side / 2));
  return { x0, y0, x1: Math.min(fd.W, x0 + side), y1: Math.min(fd.H, y0 + side) };
}
function prefetchNeighbourhoods(fd, k) {
  for (let d = 1; d <= 2; d++) {
    const e = fd.entries[k + d];
    if (e) { const nb = neighbourhood(fd, e); ensureTiles(fd, nb.x0, nb.y0, nb.x1, nb.y1).catch(() => {}); }
  }
}

// ------------------------------------------------------------------ profile and 3D view
function anchorPixel(fd, e) {  // the entry's pixel nearest its centre (a group of scattered specks has none there)
  const cx = Math.floor(e.cx), cy = Math.floor(e.cy);
  let best = [Math.min(fd.W - 1, cx), Math.min(fd.H - 1, cy)], bd = Infinity;
  for (const i of e.pix) {
    const x = i % fd.W, y = (i / fd.W) | 0, d = (x - cx) ** 2 + (y - cy) ** 2;
    if (d < bd) { bd = d; best = [x, y]; }
  }
  return best;
}
function defaultProfile(fd, e) {  // a horizontal line through the entry's pixel nearest its centre
  const half = Math.max(32, 2 * (e.x1 - e.x0));
  const [ax, y] = anchorPixel(fd, e);
  return { x0: Math.max(0, ax - half), y0: y, x1: Math.min(fd.W - 1, ax + half), y1: y, entry: e };
}

function pixelClass(fd, i) {
  if (fd.L[i]) return 'accepted';
  if (fd.fits && fd.fits.proposals && fd.fits.proposals[i]) return fd.R[i] ? 'rejected' : 'u';
  if (fd.gIds[i]) return fd.R[i] ? 'rejected' : 'g';
  if (fd.zIds[i]) return fd.R[i] ? 'rejected' : 'z';
  if (fd.sIds[i] && fd.sSize[fd.sIds[i]] >= state.sorMin) return fd.R[i] ? 'rejected' : 's';
  return null;
}

async function showViews(fd, e, t0) {
  const token = (showViews.token = (showViews.token || 0) + 1);
  const nb = neighbourhood(fd, e), pr = state.profile;
  const x0 = Math.min(nb.x0, pr.x0, pr.x1), x1 = Math.max(nb.x1, pr.x0 + 1, pr.x1 + 1);
  const y0 = Math.min(nb.y0, pr.y0, pr.y1), y1 = Math.max(nb.y1, pr.y0 + 1, pr.y1 + 1);
  try { await ensureTiles(fd, x0, y0, x1, y1); } catch (err) { showError(String(err)); return; }
  if (token !== showViews.token || state.cur !== fd) return;
  if (isNaN(e.gap) && e.src === 'L') fillLabelEntryHeights(fd, e);
  drawProfile();
  draw3d(fd, e, nb);
  requestAnimationFrame(() => {
    const ms = performance.now() - t0;
    window.zcut.viewTimes.push({ index: fd.index, entry: state.sel, profile: ms, view3d: ms });
  });
}

function fillLabelEntryHeights(fd, e) {  // heights of a painted component, from the loaded tiles
  const inE = new Set(e.pix);
  let hmin = Infinity, below = -Infinity;
  for (const i of e.pix) { const p = point(fd, i % fd.W, (i / fd.W) | 0); if (p) hmin = Math.min(hmin, -1000 * p[2]); }
  for (const i of e.pix) {
    const x = i % fd.W, y = (i / fd.W) | 0;
    for (let dy = -2; dy <= 2; dy++) for (let dx = -2; dx <= 2; dx++) {
      const xx = x + dx, yy = y + dy;
      if (xx < 0 || yy < 0 || xx >= fd.W || yy >= fd.H || inE.has(yy * fd.W + xx)) continue;
      const p = point(fd, xx, yy); if (p) below = Math.max(below, -1000 * p[2]);
    }
  }
  if (Number.isFinite(hmin)) e.hmin = hmin;
  if (Number.isFinite(below)) { e.below = below; e.gap = hmin - below; }
}

function sampleProfile(fd, pr) {  // pixels along the line, with heights (mm) and a distance (mm)
  const len = Math.hypot(pr.x1 - pr.x0, pr.y1 - pr.y0), n = Math.max(2, Math.ceil(len * 2));
  const out = [], seen = new Set();
  for (let k = 0; k <= n; k++) {
    const x = Math.round(pr.x0 + (pr.x1 - pr.x0) * k / n), y = Math.round(pr.y0 + (pr.y1 - pr.y0) * k / n);
    const i = y * fd.W + x;
    if (seen.has(i)) continue;
    seen.add(i);
    const p = point(fd, x, y);
    out.push({ t: len * k / n, i, p, h: p ? -1000 * p[2] : NaN });
  }
  // mm per pixel along the line, from neighbouring surface points (the candidates float: not them)
  const ratios = [];
  for (let k = 1; k < out.length; k++) {
    const a = out[k - 1], b = out[k];
    if (!a.p || !b.p || pixelClass(fd, a.i) || pixelClass(fd, b.i)) continue;
    ratios.push(1000 * Math.hypot(b.p[0] - a.p[0], b.p[1] - a.p[1]) / Math.max(b.t - a.t, 1e-9));
  }
  ratios.sort((a, b) => a - b);
  const mmPerPx = ratios.length ? ratios[ratios.length >> 1] : 1;
  for (const s of out) s.s = s.t * mmPerPx;
  return { samples: out, mmPerPx };
}

function niceStep(range, n) {
  const raw = range / n, p = Math.pow(10, Math.floor(Math.log10(raw))), f = raw / p;
  return (f < 1.5 ? 1 : f < 3.5 ? 2 : f < 7.5 ? 5 : 10) * p;
}

function drawProfile() {
  const fd = state.cur, pr = state.profile, cv = $('profile'), g = cv.getContext('2d');
  const dpr = window.devicePixelRatio || 1, W = Math.round(cv.clientWidth * dpr), H = Math.round(cv.clientHeight * dpr);
  if (cv.width !== W || cv.height !== H) { cv.width = W; cv.height = H; }
  g.setTransform(dpr, 0, 0, dpr, 0, 0);
  const w = cv.clientWidth, h = cv.clientHeight;
  g.fillStyle = '#121214'; g.fillRect(0, 0, w, h);
  if (!fd || !pr) { $('profinfo').textContent = ''; return; }
  const { samples, mmPerPx } = sampleProfile(fd, pr);
  const valid = samples.filter((s) => s.p);
  if (!valid.length) { $('profinfo').textContent = 'no points on this line'; return; }
  const e = pr.entry;
  let lo = Math.min(...valid.map((s) => s.h)), hi = Math.max(...valid.map((s) => s.h));
  let zoomed = false;
  if (e && e.src === 'u' && !isNaN(e.hmin)) {
    // a proposal of the fits: the height axis spans its lowest heights (at most max(4 mm, 3 × its largest
    // distance to the nearest known surface) above its lowest point) padded by that distance (at least 1 mm):
    // that surface lies within it where the group meets it, and a 1 mm distance is ~10 px tall or more
    const d = isNaN(e.distMax) ? 0 : Math.min(e.distMax, 20);
    const top = Math.min(isNaN(e.hmax) ? e.hmin : e.hmax, e.hmin + Math.max(4, 3 * d)), p = Math.max(1, 1.2 * d);
    zoomed = top + p < hi || e.hmin - p > lo;
    lo = e.hmin - p; hi = top + p;
  } else if (e && !isNaN(e.below) && !isNaN(e.hmin)) {
    // the height axis spans the group's neighbourhood (its heights and the surface below it, padded by
    // half that and at least 1.5 mm), not the bin floor to the pile top: a 1 mm gap is tens of px tall;
    // points beyond are drawn at the axis' edge
    const top = Math.max(isNaN(e.hmax) ? e.hmin : e.hmax, e.below), bot = Math.min(e.hmin, e.below);
    const p = Math.max(1.5, 0.5 * (top - bot));
    zoomed = top + p < hi || bot - p > lo;
    lo = bot - p; hi = top + p;
  } else {
    const pad = Math.max(0.5, 0.08 * (hi - lo));
    lo -= pad; hi += pad;
  }
  const sMax = samples[samples.length - 1].s || 1;
  const L = 46, R = 8, T = 10, B = 22;
  const X = (s) => L + (w - L - R) * s / sMax, Y = (v) => T + (h - T - B) * (hi - Math.min(hi, Math.max(lo, v))) / (hi - lo);
  drawProfile.axis = { lo, hi, pxPerMm: (h - T - B) / (hi - lo), zoomed };
  // axes and ticks (mm)
  g.strokeStyle = '#444'; g.fillStyle = '#9aa'; g.font = '10px system-ui'; g.lineWidth = 1;
  const hs = niceStep(hi - lo, 4);
  for (let v = Math.ceil(lo / hs) * hs; v <= hi; v += hs) {
    g.beginPath(); g.moveTo(L, Y(v)); g.lineTo(w - R, Y(v)); g.stroke();
    g.fillText(v.toFixed(hs < 1 ? 1 : 0), 2, Y(v) + 3);
  }
  const ss = niceStep(sMax, 5);
  for (let v = 0; v <= sMax; v += ss) g.fillText(`${v.toFixed(ss < 1 ? 1 : 0)}`, X(v) - 6, h - 8);
  g.fillText('mm', 2, h - 8);
  // the surface as a line, every point as a dot coloured by its class
  g.strokeStyle = '#8a8f96'; g.beginPath();
  let started = false;
  for (const s of samples) {
    if (!s.p || pixelClass(fd, s.i)) { started = false; continue; }
    if (started) g.lineTo(X(s.s), Y(s.h)); else g.moveTo(X(s.s), Y(s.h));
    started = true;
  }
  g.stroke();
  const inSel = e ? new Set(e.pix) : new Set();
  for (const s of valid) {
    const c = pixelClass(fd, s.i);
    g.fillStyle = c ? COL[c] : '#c8ccd0';
    const r = inSel.has(s.i) ? 3.5 : c ? 2.5 : 1.5;
    g.fillRect(X(s.s) - r, Y(s.h) - r, 2 * r, 2 * r);
  }
  // the gap between the selected cluster and the surface below it
  const exaggeration = ((h - T - B) / (hi - lo)) / ((w - L - R) / sMax);  // screen px per mm: vertical / horizontal
  let info = `heights ×${exaggeration < 10 ? exaggeration.toFixed(1) : exaggeration.toFixed(0)}, ${mmPerPx.toFixed(2)} mm/px` +
    (zoomed ? ` · height axis zoomed to the group (${lo.toFixed(1)}…${hi.toFixed(1)} mm; points beyond at its edge)` : '');
  if (e && !isNaN(e.gap) && !isNaN(e.below)) {
    const onLine = valid.filter((s) => inSel.has(s.i));
    const xs = onLine.length ? X(onLine.reduce((a, s) => a + s.s, 0) / onLine.length) : X(sMax / 2);
    g.setLineDash([4, 3]); g.strokeStyle = COL.sel;
    for (const v of [e.hmin, e.below]) { g.beginPath(); g.moveTo(xs - 30, Y(v)); g.lineTo(xs + 30, Y(v)); g.stroke(); }
    g.setLineDash([]);
    g.beginPath(); g.moveTo(xs, Y(e.hmin)); g.lineTo(xs, Y(e.below)); g.stroke();
    for (const [v, d] of [[e.hmin, 1], [e.below, -1]]) {
      g.beginPath(); g.moveTo(xs - 4, Y(v) + 6 * d); g.lineTo(xs, Y(v)); g.lineTo(xs + 4, Y(v) + 6 * d); g.stroke();
    }
    g.fillStyle = COL.sel; g.font = 'bold 12px system-ui';
    const label = e.gap >= 0 ? `gap ${e.gap.toFixed(2)} mm` : `${(-e.gap).toFixed(2)} mm below`;
    g.fillText(label, Math.min(xs + 8, w - R - g.measureText(label).width), (Y(e.hmin) + Y(e.below)) / 2 + 4);
    info = (e.gap >= 0 ? `gap ${e.gap.toFixed(2)} mm above the surface` : `${(-e.gap).toFixed(2)} mm below the surface`) + ` · ${info}`;
  }
  if (e && e.src === 'u') {
    info = (isNaN(e.dist) ? `the pixels of rejected fit #${e.fromFit + 1}` :
      `${e.dist.toFixed(2)} mm from the nearest known surface (median; largest ${e.distMax.toFixed(2)} mm; ` +
      `${fd.fits.header.k} × Err = ${(fd.fits.header.k * e.err).toFixed(2)} mm)` +
      (e.fromFit >= 0 ? `, pixels of rejected fit #${e.fromFit + 1}` : '')) + ` · ${info}`;
  }
  $('profinfo').textContent = info;
}

function draw3d(fd, e, nb) {
  if (!view3d) return;
  const pos = [], col = [], big = [], bigCol = [];
  const inSel = new Set(e.pix);
  // the origin: the middle of the points' bounding box (the cluster and the surface below both in view)
  let x0 = Infinity, x1 = -Infinity, y0 = Infinity, y1 = -Infinity, z0 = Infinity, z1 = -Infinity;
  for (let y = nb.y0; y < nb.y1; y++) for (let x = nb.x0; x < nb.x1; x++) {
    const p = point(fd, x, y); if (!p) continue;
    x0 = Math.min(x0, p[0]); x1 = Math.max(x1, p[0]); y0 = Math.min(y0, p[1]); y1 = Math.max(y1, p[1]);
    z0 = Math.min(z0, p[2]); z1 = Math.max(z1, p[2]);
  }
  if (!Number.isFinite(x0)) { view3d.clear(); $('v3info').textContent = 'no points here'; return; }
  const ox = (x0 + x1) / 2, oy = (y0 + y1) / 2, oz = (z0 + z1) / 2;
  const hs = [];
  for (let y = nb.y0; y < nb.y1; y++) for (let x = nb.x0; x < nb.x1; x++) { const p = point(fd, x, y); if (p) hs.push(-1000 * p[2]); }
  hs.sort((a, b) => a - b);
  const hlo = hs[Math.floor(0.02 * (hs.length - 1))], hhi = hs[Math.floor(0.98 * (hs.length - 1))];
  for (let y = nb.y0; y < nb.y1; y++) for (let x = nb.x0; x < nb.x1; x++) {
    const p = point(fd, x, y); if (!p) continue;
    const i = y * fd.W + x, cls = pixelClass(fd, i);
    let rgb;
    if (cls) rgb = RGB[cls];
    else { const t = Math.max(0, Math.min(1, (-1000 * p[2] - hlo) / Math.max(hhi - hlo, 1e-6))); const v = 70 + 150 * t; rgb = [v, v, v + 8]; }
    const q = [1000 * (p[0] - ox), -1000 * (p[1] - oy), -1000 * (p[2] - oz)];
    if (inSel.has(i)) { big.push(...q); bigCol.push(...(cls ? RGB[cls] : [255, 255, 255])); } else { pos.push(...q); col.push(...rgb); }
  }
  const radius = 500 * Math.hypot(x1 - x0, y1 - y0, z1 - z0) || 20;  // of the points' bounding sphere, mm
  const fp = fitPoints(fd, nb, ox, oy, oz, e);  // the fitted instances: their models' surface points
  pos.push(...fp.pos); col.push(...fp.col);
  view3d.setPoints(new Float32Array([...big, ...pos]), new Uint8Array([...bigCol, ...col]), big.length / 3, Math.max(radius, 5));
  $('v3info').textContent = `${(big.length + pos.length - fp.pos.length) / 3} points` +
    (fp.pos.length ? ` + fitted models (blue; white: selected, magenta: rejected)` : '') +
    (e.src === 'f' ? ` · fit #${e.id}: Err ${e.err.toFixed(3)} mm` : '') + ` · ${view3d.kind} · drag to turn`;
}

// ------------------------------------------------------------------ overlay + drawing
const canvas = $('canvas'), ctx = canvas.getContext('2d');
let view3d = null;
try { view3d = new PointView($('view3d')); } catch (e) { showError(`3D view: ${e}`); }

function ensureOvCanvas(fd) {
  if (fd.ovCanvas) return;
  fd.ovCanvas = document.createElement('canvas');
  fd.ovCanvas.width = fd.W; fd.ovCanvas.height = fd.H;
  fd.octx = fd.ovCanvas.getContext('2d');
  fd.octx.putImageData(fd.ovImg, 0, 0);
  if (fd.ovBmp) { fd.ovBmp.close(); fd.ovBmp = null; }
}

function shadeUnreviewed(fd) { return fd.nR > 0 && 2 * fd.nR >= fd.nValid; }
function countR(fd) { let n = 0; const R = fd.R; for (let i = 0; i < R.length; i++) n += R[i]; fd.nR = n; }

function renderOverlay(x0 = 0, y0 = 0, x1 = null, y1 = null) {
  const fd = state.cur; if (!fd) return;
  ensureOvCanvas(fd);
  const W = fd.W, ov32 = fd.ov32;
  const shade = shadeUnreviewed(fd);
  if ((x1 === null && y1 === null && x0 === 0 && y0 === 0) || shade !== fd.ovShade) {
    fd.ovFlags = flags(); fd.ovShade = shade; x0 = 0; y0 = 0; x1 = null; y1 = null;
  }
  x1 = x1 === null ? fd.W : Math.min(x1, fd.W); y1 = y1 === null ? fd.H : Math.min(y1, fd.H);
  x0 = Math.max(0, x0 | 0); y0 = Math.max(0, y0 | 0); x1 = Math.ceil(x1); y1 = Math.ceil(y1);
  if (x1 <= x0 || y1 <= y0) return;
  const { R, valid, zIds, sIds, sSize } = fd;
  const c = fd.conflict, cv = c && c.theirs ? state.conflictView : 'mine';
  const L = cv === 'theirs' ? c.theirs.L : fd.L, other = cv === 'diff' ? c.theirs.L : null;
  const sL = state.showL, sZ = state.showZ, sS = state.showS, sG = state.showG, sorMin = state.sorMin, gIds = fd.gIds;
  const fits = fd.fits && fd.fits.fit_ids ? fd.fits : null, fIds = fits && state.showF ? fits.fit_ids : null;
  const uIds = fits ? fits.proposals : null;
  const fx = fd.fitEntries || [];
  for (let y = y0; y < y1; y++) {
    let i = y * W + x0;
    for (let x = x0; x < x1; x++, i++) {
      let col = 0;
      if (other && L[i] !== other[i]) col = COL_DIFF;
      else if (sL && L[i]) col = COL_L;
      else {
        const z = sZ && zIds[i] !== 0, s = sS && sIds[i] !== 0 && sSize[sIds[i]] >= sorMin;
        const f = fIds ? fIds[i] : 0;
        if (uIds && uIds[i] !== 0) col = R[i] ? COL_UR : COL_U;  // a proposal's pixel: undecided, not outlier
        // a fit's outline: its pixels next to a valid pixel not its own (not every hole's rim: on a ray-traced
        // frame those made most of the pile lime)
        else if (f && ((x > 0 && fIds[i - 1] !== f && valid[i - 1]) || (x < W - 1 && fIds[i + 1] !== f && valid[i + 1]) ||
                       (y > 0 && fIds[i - W] !== f && valid[i - W]) || (y < fd.H - 1 && fIds[i + W] !== f && valid[i + W]))) {
          col = fx[f - 1] && fx[f - 1].rejected ? COL_FITX : COL_FIT;
        }
        else if (sG && gIds[i] !== 0) col = R[i] ? COL_GR : COL_G;
        else if (z) col = s ? COL_ZS : COL_Z; else if (s) col = COL_S;
        else if (shade && valid[i] && !R[i]) col = COL_UNREV;
      }
      ov32[i] = col;
    }
  }
  fd.octx.putImageData(fd.ovImg, 0, 0, x0, y0, x1 - x0, y1 - y0);
  fd.ovVersion = (fd.ovVersion || 0) + 1;
}

let drawQueued = false;
function requestDraw() {
  if (drawQueued) return;
  drawQueued = true;
  requestAnimationFrame(() => { drawQueued = false; draw(); });
}

function draw() {
  const t0 = performance.now();
  drawFrame();
  const z = window.zcut.drawTimes;
  z.push(performance.now() - t0); if (z.length > 500) z.splice(0, z.length - 500);
}
function drawFrame() {
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
  if (state.showOv) ctx.drawImage(fd.ovCanvas || fd.ovBmp, 0, 0);
  drawOutlines(fd);
  // tool previews (image coordinates)
  ctx.lineWidth = 1.5 / state.zoom; ctx.strokeStyle = '#fff';
  if (drag && drag.kind === 'box') {
    ctx.strokeRect(drag.x0, drag.y0, drag.x - drag.x0, drag.y - drag.y0);
  } else if (drag && drag.kind === 'lasso' && drag.pts.length > 1) {
    ctx.beginPath(); ctx.moveTo(drag.pts[0][0], drag.pts[0][1]);
    for (const [x, y] of drag.pts) ctx.lineTo(x, y);
    ctx.stroke();
  }
  if (hover && ['brush', 'eraser', 'unreviewed', 'rbrush'].includes(state.tool)) {
    ctx.beginPath(); ctx.arc(hover.x, hover.y, state.brush, 0, 2 * Math.PI); ctx.stroke();
  }
  // screen space: candidate markers (visible at any zoom), the profile line
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  drawMarkers(fd);
  if (!state.showOv) {  // the overlay hidden: the image as it is, and a word that it is hidden
    ctx.font = '12px system-ui'; ctx.fillStyle = 'rgba(0,0,0,0.6)'; ctx.fillRect(6, 6, 150, 18);
    ctx.fillStyle = '#fc6'; ctx.fillText('overlay hidden (O)', 12, 19);
  }
  const pr = state.profile;
  if (pr) {
    const a = toScreen(pr.x0 + 0.5, pr.y0 + 0.5), b = toScreen(pr.x1 + 0.5, pr.y1 + 0.5);
    ctx.setLineDash([6, 4]); ctx.strokeStyle = '#7fe3ff'; ctx.lineWidth = 1.5;
    ctx.beginPath(); ctx.moveTo(a.x, a.y); ctx.lineTo(b.x, b.y); ctx.stroke(); ctx.setLineDash([]);
  }
  if (drag && drag.kind === 'profile') {
    const a = toScreen(drag.x0, drag.y0), b = toScreen(drag.x, drag.y);
    ctx.strokeStyle = '#7fe3ff'; ctx.beginPath(); ctx.moveTo(a.x, a.y); ctx.lineTo(b.x, b.y); ctx.stroke();
  }
  drawMinimap(fd);
  drawLegend(fd, hover ? state.cursorH : undefined);
}

function toScreen(x, y) { return { x: state.px + x * state.zoom, y: state.py + y * state.zoom }; }

// The proposal under the pointer (its outline and ring are drawn, as the selected entry's), or null.
function hoverEntry(fd) {
  if (!hover || !fd.propEntries || !fd.propEntries.length || !fd.fits || !fd.fits.proposals) return null;
  const x = Math.floor(hover.x), y = Math.floor(hover.y);
  if (x < 0 || y < 0 || x >= fd.W || y >= fd.H) return null;
  const u = fd.fits.proposals[y * fd.W + x];
  return u ? fd.propEntries[u - 1] || null : null;
}
function hoverFit(fd) { return hover && state.showOv ? fitAt(fd, hover.x, hover.y) : null; }  // outlined, as K takes it

// The outline of an entry's pixels: the sides of its pixels that face a pixel not in it, as line segments
// (image coordinates), computed once per entry.
function outlineOf(fd, e) {
  if (e.outline) return e.outline;
  const W = fd.W, H = fd.H;
  if (!fd.mark || fd.mark.length !== W * H) fd.mark = new Uint8Array(W * H);
  const m = fd.mark, seg = [];
  for (const i of e.pix) m[i] = 1;
  for (const i of e.pix) {
    const x = i % W, y = (i / W) | 0;
    if (x === 0 || !m[i - 1]) seg.push(x, y, x, y + 1);
    if (x === W - 1 || !m[i + 1]) seg.push(x + 1, y, x + 1, y + 1);
    if (y === 0 || !m[i - W]) seg.push(x, y, x + 1, y);
    if (y === H - 1 || !m[i + W]) seg.push(x, y + 1, x + 1, y + 1);
  }
  for (const i of e.pix) m[i] = 0;
  e.outline = Float32Array.from(seg);
  return e.outline;
}
function drawOutlines(fd) {  // image space: the selected entry's and the hovered proposal's pixels, outlined
  if (!fd.entries) return;
  const sel = state.sel >= 0 ? fd.entries[state.sel] : null, hov = state.showOv ? hoverEntry(fd) || hoverFit(fd) : null;
  for (const e of hov && hov !== sel ? [hov, sel] : [sel]) {
    if (!e || !e.pix || e.pix.length > 200000) continue;
    const s = outlineOf(fd, e);
    ctx.beginPath();
    for (let k = 0; k < s.length; k += 4) { ctx.moveTo(s[k], s[k + 1]); ctx.lineTo(s[k + 2], s[k + 3]); }
    ctx.lineWidth = 3 / state.zoom; ctx.strokeStyle = 'rgba(0,0,0,0.8)'; ctx.stroke();
    ctx.lineWidth = 1.5 / state.zoom; ctx.strokeStyle = e === sel ? COL.sel : e.src === 'f' ? '#d8ff80' : '#ffe97a'; ctx.stroke();
  }
}

function drawMarkers(fd) {
  if (!fd.entries) return;
  const vw = canvas.clientWidth, vh = canvas.clientHeight;
  const states = fd.states || [];
  const rank = { f: -1, s: 0, L: 1, g: 1, u: 2, z: 2 };  // z-cut drawn last (on top), the selected one after all
  const hov = state.showOv ? hoverEntry(fd) : null;
  if (state.showOv) drawFitLabels(fd);
  // a marker for each review group (and z-cut / SOR / painted entry); the fits' proposals have none but the
  // hovered one's (their pixels are the tinted mask: thousands of rings would hide the pile); nothing but the
  // selected entry's while the overlay is hidden (O)
  const order = [];
  fd.entries.forEach((e, k) => {
    if (k === state.sel || e.src === 'f') return;  // a fit: its outline and Err label (drawFitLabels)
    if (e.src === 'u' ? e === hov : state.showOv) order.push(k);
  });
  order.sort((a, b) => rank[fd.entries[a].src] - rank[fd.entries[b].src]);
  if (state.sel >= 0 && state.sel < fd.entries.length) order.push(state.sel);
  drawMarkers.drawn = order.map((k) => ({ src: fd.entries[k].src, id: fd.entries[k].id, sel: k === state.sel }));
  order.forEach((k) => {
    const e = fd.entries[k];
    // a ring of at least 7 px around a small cluster, a box around a large one: seen at any zoom
    const c = toScreen(e.cx, e.cy), p0 = toScreen(e.x0, e.y0), p1 = toScreen(e.x1, e.y1);
    const big = Math.max(p1.x - p0.x, p1.y - p0.y) > 24;
    const r = big ? Math.hypot(p1.x - p0.x, p1.y - p0.y) / 2 : Math.max(7, 0.5 * Math.hypot(p1.x - p0.x, p1.y - p0.y) + 4);
    if (c.x < -r || c.y < -r || c.x > vw + r || c.y > vh + r) return;
    const st = states[k] || 'undecided';
    ctx.strokeStyle = st === 'undecided' ? COL[e.src] : COL[st];
    ctx.lineWidth = k === state.sel ? 3 : 1.5;
    // a merged group's pixels scattered over a wide box: its box faint unless selected (its pixels are drawn)
    const sparse = big && k !== state.sel && e.n < 0.02 * Math.max(1, (e.x1 - e.x0) * (e.y1 - e.y0));
    if (sparse) { ctx.globalAlpha = 0.3; ctx.lineWidth = 1; }
    if (st === 'rejected') ctx.setLineDash([3, 3]);
    ctx.beginPath();
    if (big) ctx.rect(p0.x - 3, p0.y - 3, p1.x - p0.x + 6, p1.y - p0.y + 6); else ctx.arc(c.x, c.y, r, 0, 2 * Math.PI);
    ctx.stroke();
    ctx.setLineDash([]);
    ctx.globalAlpha = 1;
    if (e.src === 'z' && !big && st === 'undecided') {  // a z-cut candidate: a dot in its ring as well
      ctx.fillStyle = COL.z; ctx.beginPath(); ctx.arc(c.x, c.y, 2.5, 0, 2 * Math.PI); ctx.fill();
    }
    if (k === state.sel) {
      ctx.strokeStyle = COL.sel; ctx.lineWidth = 2;
      ctx.beginPath(); ctx.arc(c.x, c.y, r + 5, 0, 2 * Math.PI); ctx.stroke();
      for (const [dx, dy] of [[1, 0], [-1, 0], [0, 1], [0, -1]]) {
        ctx.beginPath(); ctx.moveTo(c.x + dx * (r + 6), c.y + dy * (r + 6)); ctx.lineTo(c.x + dx * (r + 16), c.y + dy * (r + 16)); ctx.stroke();
      }
    }
  });
}

function drawFitLabels(fd) {  // each fit's Err (mm) at its centre, where it is at least 26 px wide on screen
  const vw = canvas.clientWidth, vh = canvas.clientHeight;
  ctx.font = 'bold 11px system-ui'; ctx.textAlign = 'center';
  for (const e of fd.fitEntries || []) {
    if ((e.x1 - e.x0) * state.zoom < 26 && !(state.sel >= 0 && fd.entries[state.sel] === e)) continue;
    const c = toScreen(e.cx, e.cy);
    if (c.x < -40 || c.y < -20 || c.x > vw + 40 || c.y > vh + 20) continue;
    const t = e.rejected ? `✗ ${e.err.toFixed(2)}` : e.err.toFixed(2);
    ctx.lineWidth = 3; ctx.strokeStyle = 'rgba(0,0,0,0.8)'; ctx.strokeText(t, c.x, c.y + 4);
    ctx.fillStyle = e.rejected ? '#ff40ff' : '#d8ff80'; ctx.fillText(t, c.x, c.y + 4);
  }
  ctx.textAlign = 'start';
}

function drawMinimap(fd) {
  const mm = $('minimap');
  mm.hidden = !state.showMini;
  if (!state.showMini) return;
  const dpr = window.devicePixelRatio || 1, w = Math.max(120, Math.min(250, mm.parentElement.clientWidth - 22));
  const h = Math.round(w * fd.H / fd.W);
  if (mm.width !== w * dpr || mm.height !== h * dpr) { mm.width = w * dpr; mm.height = h * dpr; mm.style.width = `${w}px`; mm.style.height = `${h}px`; }
  const g = mm.getContext('2d');
  g.setTransform(1, 0, 0, 1, 0, 0);
  const small = fd.small[viewKind()] || fd.small.rgb || fd.small.height;
  if (small) g.drawImage(small, 0, 0, mm.width, mm.height); else { g.fillStyle = '#000'; g.fillRect(0, 0, mm.width, mm.height); }
  if (state.showOv) {  // the overlay, shrunk (once per change of it): where the proposals are, by state
    const ov = fd.ovCanvas || fd.ovBmp;
    if (ov && (!fd.ovSmall || fd.ovSmallAt !== fd.ovVersion || fd.ovSmall.width !== mm.width || fd.ovSmall.height !== mm.height)) {
      if (!fd.ovSmall) fd.ovSmall = document.createElement('canvas');
      fd.ovSmall.width = mm.width; fd.ovSmall.height = mm.height;
      const sg = fd.ovSmall.getContext('2d');
      sg.imageSmoothingEnabled = true; sg.drawImage(ov, 0, 0, mm.width, mm.height);
      fd.ovSmallAt = fd.ovVersion;
    }
    if (ov) g.drawImage(fd.ovSmall, 0, 0);
  }
  g.setTransform(dpr * w / fd.W, 0, 0, dpr * h / fd.H, 0, 0);
  const s = fd.W / w;
  (fd.entries || []).forEach((e, k) => {
    if (k !== state.sel && (e.src === 'f' || e.src === 'u' || !state.showOv)) return;  // fits outlined, proposals tinted
    const st = (fd.states || [])[k] || 'undecided';
    g.fillStyle = k === state.sel ? COL.sel : st === 'undecided' ? COL[e.src] : COL[st];
    const r = (k === state.sel ? 3.5 : 2) * s;
    g.fillRect(e.cx - r, e.cy - r, 2 * r, 2 * r);
  });
  g.strokeStyle = '#fff'; g.lineWidth = 1.2 * s;
  const vx = -state.px / state.zoom, vy = -state.py / state.zoom;
  g.strokeRect(vx, vy, canvas.clientWidth / state.zoom, canvas.clientHeight / state.zoom);
}

function fitZoom(fd) { return Math.min(canvas.clientWidth / fd.W, canvas.clientHeight / fd.H); }
function fit(redraw = true) {
  const fd = state.cur; if (!fd) return;
  const vw = canvas.clientWidth, vh = canvas.clientHeight;
  state.zoom = fitZoom(fd);
  state.px = (vw - fd.W * state.zoom) / 2; state.py = (vh - fd.H * state.zoom) / 2;
  if (redraw) requestDraw();
}
function zoomToBox(x0, y0, x1, y1) {  // a box of the image, with a margin, fills the view
  const fd = state.cur, vw = canvas.clientWidth, vh = canvas.clientHeight;
  const m = 0.15 * Math.max(x1 - x0, y1 - y0) + 16;
  state.zoom = Math.max(fitZoom(fd), Math.min(24, Math.min(vw / (x1 - x0 + 2 * m), vh / (y1 - y0 + 2 * m))));
  state.px = vw / 2 - (x0 + x1) / 2 * state.zoom; state.py = vh / 2 - (y0 + y1) / 2 * state.zoom;
}
function zoomTo(e) {  // the cluster's neighbourhood fills about half the view
  const fd = state.cur, nb = neighbourhood(fd, e);
  const vw = canvas.clientWidth, vh = canvas.clientHeight, side = Math.max(nb.x1 - nb.x0, nb.y1 - nb.y0);
  state.zoom = Math.max(fitZoom(fd), Math.min(24, 0.5 * Math.min(vw, vh) / side));
  state.px = vw / 2 - e.cx * state.zoom; state.py = vh / 2 - e.cy * state.zoom;
  requestDraw();
}

// ------------------------------------------------------------------ height legend and read-out
function drawLegend(fd, hCursor) {
  const box = $('legend');
  box.hidden = !(state.showH && fd && state.turbo);
  if (box.hidden) return;
  const cv = $('legendbar'), g = cv.getContext('2d'), lo = fd.header.height_lo_mm, hi = fd.header.height_hi_mm;
  const w = 16, h = 160;
  if (cv.width !== w || cv.height !== h) { cv.width = w; cv.height = h; }
  for (let y = 0; y < h; y++) {
    const c = state.turbo[Math.round(255 * (1 - y / (h - 1)))];
    g.fillStyle = `rgb(${c[0]},${c[1]},${c[2]})`; g.fillRect(0, y, w, 1);
  }
  if (hCursor !== undefined && !isNaN(hCursor)) {
    const y = Math.max(0, Math.min(h - 1, (hi - hCursor) / (hi - lo) * (h - 1)));
    g.fillStyle = '#fff'; g.fillRect(0, y - 1, w, 3); g.fillStyle = '#000'; g.fillRect(0, y, w, 1);
  }
  $('legendhi').textContent = `${hi.toFixed(1)} mm`;
  $('legendlo').textContent = `${lo.toFixed(1)} mm`;
}

let readoutQueued = false;
function updateReadout() {
  if (readoutQueued) return;
  readoutQueued = true;
  requestAnimationFrame(() => { readoutQueued = false; readout(); });
}
function readout() {
  const fd = state.cur, box = $('readout');
  if (!fd || !hover) { box.textContent = ''; return; }
  const x = Math.floor(hover.x), y = Math.floor(hover.y);
  state.cursorH = undefined;
  if (x < 0 || y < 0 || x >= fd.W || y >= fd.H) { box.textContent = ''; drawLegend(fd); return; }
  const i = y * fd.W + x;
  const p = point(fd, x, y);
  if (!p && !fd.tiles.get(tileKey(Math.floor(x / TILE), Math.floor(y / TILE)))) {
    ensureTiles(fd, x, y, x + 1, y + 1).then(updateReadout, () => {});
  }
  const parts = [`row ${y} col ${x}`];
  if (p) {
    const hmm = -1000 * p[2];
    state.cursorH = hmm;
    parts.push(`height ${hmm.toFixed(2)} mm`, `x ${(1000 * p[0]).toFixed(2)} y ${(1000 * p[1]).toFixed(2)} z ${(1000 * p[2]).toFixed(2)} mm`);
    drawLegend(fd, hmm);
  } else {
    parts.push(fd.valid[i] ? 'height …' : 'no point'); drawLegend(fd);
  }
  if (fd.zone && fd.valid[i] && !fd.zone[i]) parts.push('table / bin (not judged)');
  const cls = pixelClass(fd, i);
  const fe = fitAt(fd, x, y);
  if (fe) parts.push(`fit #${fe.id} (Err ${fe.err.toFixed(2)} mm${fe.rejected ? ', rejected' : ''})`);
  if (fd.fits && fd.fits.proposals && fd.fits.proposals[i]) {
    const pe = (fd.propEntries || [])[fd.fits.proposals[i] - 1];
    if (pe) parts.push((pe.fromFit >= 0 ? `rejected fit #${pe.fromFit + 1}'s pixels` : 'unexplained') +
      (isNaN(pe.dist) ? '' : `: group ${pe.dist.toFixed(2)} mm off`));
  }
  if (fd.zIds[i]) parts.push(`z-cut #${fd.zIds[i]}`);
  if (fd.sIds[i]) parts.push(`SOR #${fd.sIds[i]} (${fd.sSize[fd.sIds[i]]} px)`);
  parts.push(fd.L[i] ? 'labelled outlier' : fd.R[i] ? 'reviewed, not outlier' : cls ? 'undecided' : 'not reviewed');
  box.textContent = parts.join(' · ');
}

// ------------------------------------------------------------------ the list holds still under the pointer
// What reaches the page on its own — the assistant's proposals (whenever the server has retrained on the labels
// saved) and the fits — re-orders the list: a row the person is about to click would move and the click decide
// another group (a scripted person in a real browser decided the wrong group 0-2 times a frame this way; docs/
// labelling_real.md). While the pointer is over the list such updates of the frame shown wait, the line below the
// list says so (not the heading above it: a longer heading would move the rows), and they are applied when the
// pointer leaves the list (or when the frame is shown again). What the person's own inputs change (a decision, K,
// Ctrl+click) applies at once.
let listHeld = false;
function heldText(fd) {
  return fd && fd.held && fd.held.size ? `new ${[...fd.held.keys()].join(' and ')}: shown when the pointer leaves the list` : '';
}
function whenListFree(fd, apply, what) {
  if (listHeld && state.cur === fd) {
    (fd.held || (fd.held = new Map())).set(what, apply);  // the latest of each kind
    const a = $('assistinfo'); if (a) a.textContent = a.title = heldText(fd);
    window.zcut.heldUpdates = (window.zcut.heldUpdates || 0) + 1;
  } else apply();
}
function applyHeld(fd) {
  if (!fd || !fd.held || !fd.held.size) return;
  const held = [...fd.held.values()]; fd.held = null;
  for (const apply of held) apply();
}
$('candlist').addEventListener('mouseenter', () => { listHeld = true; });
$('candlist').addEventListener('mouseleave', () => {
  listHeld = false;
  if (state.cur && state.cur.held && state.cur.held.size) { applyHeld(state.cur); renderList(); requestDraw(); }
});

// ------------------------------------------------------------------ the assistant's proposals
let assistantVersion = -1;
async function loadProposals(fd) {
  try {
    const r = await fetch(`/api/frames/${fd.index}/proposals`);
    if (!r.ok) return;
    const j = await r.json();
    const prop = { p: j.p, prefill: j.prefill, why_not: j.why_not, version: j.version, message: j.message,
                   confident: j.confident, model: j.model };
    assistantVersion = Math.max(assistantVersion, j.version);
    whenListFree(fd, () => { fd.prop = prop; if (state.cur === fd) { refreshList(fd, true); requestDraw(); } }, 'proposals');
    window.zcut.proposalsLoaded = (window.zcut.proposalsLoaded || 0) + 1;
  } catch (e) { /* the next poll tries again */ }
}
async function pollAssistant() {
  try {
    const r = await fetch('/api/assistant');
    if (r.ok) {
      const j = await r.json();
      window.zcut.assistant = j;
      if (j.version !== assistantVersion && state.cur) { assistantVersion = j.version; await loadProposals(state.cur); }
      else if (state.cur && !state.cur.prop && !(state.cur.held && state.cur.held.has('proposals'))) await loadProposals(state.cur);
    }
  } catch (e) { /* the server may be gone: the save path says so */ }
  setTimeout(pollAssistant, 1500);
}

// A frame the bin stages skipped: say why at once (the zone is every valid pixel, table and bin included).
function showFrameWarning(fd) {
  const el = $('framewarn'), w = fd.header.warnings || [];
  if (!fd.header.bin_stages) {
    el.textContent = `Frame ${fd.index}: ${w.join('; ') || 'bin stages skipped'}. Without the bin stages the ` +
      'filters judge every valid point, table and bin included, so they propose little; the review groups ' +
      'still cover the whole frame. If the scan shows a bin, give its model (zcut annotate --bin-model BIN.ply) ' +
      'so that only what lies inside the bin is judged.';
    el.hidden = false;
  } else if (w.length) { el.textContent = `Frame ${fd.index}: ${w.join('; ')}`; el.hidden = false; }
  else el.hidden = true;
}

// ------------------------------------------------------------------ part fits (docs/labelling.md, "Judging fits")
// With a part model the server fits the part's instances in the background (annotate/fits.py): each fitted
// instance is outlined over the image with its residual Err, listed ('f' entries) and drawn in the 3D view;
// the unexplained pixels (farther than k × Err from every known surface) are the proposals ('u' entries),
// each with its distance to the nearest known surface. K rejects the selected fit (or the one under the
// pointer): the server judges its pixels again against the surfaces left (the other fits, the bin, the table)
// and those none explains return to review as proposals of their own, with their distance ("fit #n rej.",
// "x.x mm off"); K again takes the rejection back (the server's answer is then the one it gave before).
// The proposals are drawn as a per-pixel tint by state (no marker but the selected's and the hovered one's): undecided
// yellow, outlier red (the labels' colour), not outlier green; translucent enough that the image reads through.
const COL_FIT = rgba(170, 255, 0, 120), COL_FITX = rgba(255, 0, 255, 230), COL_U = rgba(255, 235, 0, 150);
const COL_UR = rgba(95, 211, 141, 120);
function parseFitsBundle(buf) {  // an uncompressed bundle of annotate/payload.py: sparse ids and tables
  const dv = new DataView(buf), n = dv.getUint32(0, true);
  const header = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, 4, n)));
  const base = 4 + n, out = {}, size = header.width * header.height;
  for (const s of header.sections || []) {
    const bytes = new Uint8Array(buf.slice(base + s.offset, base + s.offset + s.length));
    if (s.kind === 'sparse') {
      const c = s.count, deltas = new Uint32Array(bytes.buffer, 0, c);
      const T = { uint8: Uint8Array, uint16: Uint16Array, uint32: Uint32Array }[s.dtype];
      const vals = new T(bytes.buffer.slice(4 * c, 4 * c + c * T.BYTES_PER_ELEMENT));
      const a = new Uint32Array(size);
      let i = 0;
      for (let k = 0; k < c; k++) { i += deltas[k]; a[i] = vals[k]; }
      out[s.name] = a;
    } else if (s.kind === 'table') out[s.name] = new Float32Array(bytes.buffer);
  }
  return { header, ...out };
}
function tableRows(t, cols) {
  const nc = cols.length, col = Object.fromEntries(cols.map((c, i) => [c, i])), rows = [];
  for (let r = 0; t && r < t.length / nc; r++) rows.push((name) => t[r * nc + col[name]]);
  return rows;
}
function pixelsOf(ids, n) {  // id (1..n) -> Int32Array of its pixels
  const count = new Int32Array(n + 2);
  for (let i = 0; i < ids.length; i++) if (ids[i]) count[ids[i] + 1]++;
  for (let k = 1; k < count.length; k++) count[k] += count[k - 1];
  const pix = new Int32Array(count[n + 1]), at = count.slice();
  for (let i = 0; i < ids.length; i++) if (ids[i]) pix[at[ids[i]]++] = i;
  return (id) => pix.subarray(count[id], count[id + 1]);
}
function applyFits(fd, f) {
  const had = (fd.fitEntries || []).length + (fd.propEntries || []).length;
  const selE = state.cur === fd && state.sel >= 0 ? fd.entries[state.sel] : null;  // kept selected
  fd.fits = f;
  const h = f.header;
  fd.fitEntries = []; fd.propEntries = [];
  if (h.status === 'ready') {
    const fpix = pixelsOf(f.fit_ids, h.n_fits), ppix = pixelsOf(f.proposals, h.n_proposals);
    for (const v of tableRows(f.fit_table, h.fit_columns)) {
      const i = v('fit'), pose = ['r00', 'r01', 'r02', 't0', 'r10', 'r11', 'r12', 't1', 'r20', 'r21', 'r22', 't2'].map(v);
      fd.fitEntries.push({ src: 'f', id: i + 1, fit: i, n: v('n'), x0: v('x0'), y0: v('y0'), x1: v('x1'), y1: v('y1'),
        cx: v('cx'), cy: v('cy'), err: v('err_mm'), support: v('support'), rejected: v('rejected') > 0, pose,
        seeded: v('seeded') > 0, proposed: v('proposed'),
        hmin: NaN, hmax: NaN, below: NaN, gap: NaN, score: v('err_mm'), both: 0, also: [], pix: fpix(i + 1) });
    }
    for (const v of tableRows(f.proposal_table, h.proposal_columns)) {
      const id = v('id');
      fd.propEntries.push({ src: 'u', id, n: v('n'), x0: v('x0'), y0: v('y0'), x1: v('x1'), y1: v('y1'), cx: v('cx'),
        cy: v('cy'), hmin: v('h_min_mm'), hmax: v('h_max_mm'), below: NaN, gap: NaN, dist: v('dist_mm'),
        distMax: v('dist_max_mm'), err: v('err_mm'), fromFit: v('fit'), score: 1e6 + (isNaN(v('dist_mm')) ? 1e3 : v('dist_mm')),
        both: 0, also: [], pix: ppix(id) });
    }
  }
  if (had || fd.fitEntries.length || fd.propEntries.length) {  // no part model: the list stays as it is
    buildEntries(fd);
    if (selE && state.cur === fd) {
      state.sel = fd.entries.findIndex((e) => e.src === selE.src && e.id === selE.id);
      renderList();
    }
  }
  if (state.cur === fd) { renderOverlay(); requestDraw(); showFitInfo(fd); }
}
function showFitInfo(fd) {
  const el = $('fitinfo'); if (!el) return;
  const f = fd.fits;
  if (!f) { el.textContent = 'fits: …'; return; }
  const h = f.header;
  if (h.status === 'ready') {
    const errs = fd.fitEntries.map((e) => e.err).sort((a, b) => a - b);
    el.textContent = `${h.n_fits} fits of ${h.model} (median Err ${errs.length ? errs[errs.length >> 1].toFixed(2) : '–'} mm` +
      `${h.n_rejected ? `, ${h.n_rejected} rejected` : ''}) · ${h.n_proposals} proposals: pixels farther than ` +
      `${h.k} × Err from every known surface`;
  } else el.textContent = h.status === 'none' ? h.message : h.status === 'error' ? `no fits: ${h.message}` : 'fitting…';
  el.className = `info fits ${h.status}`;
}
async function loadFits(fd) {
  try {
    const r = await fetch(`/api/frames/${fd.index}/fits`);
    if (!r.ok) throw new Error(`fits: HTTP ${r.status}`);
    const f = parseFitsBundle(await r.arrayBuffer());
    if (f.header.status === 'ready' || f.header.status === 'none' || f.header.status === 'error') whenListFree(fd, () => applyFits(fd, f), 'fits');
    else {
      fd.fits = f; if (state.cur === fd) showFitInfo(fd);
      setTimeout(() => { if (state.cur === fd) loadFits(fd); }, 1000);
    }
  } catch (e) { setTimeout(() => { if (state.cur === fd) loadFits(fd); }, 2000); }
}
function fitAt(fd, x, y) {  // the fit entry whose pixels hold (x, y), or null
  if (!fd.fits || !fd.fits.fit_ids || x < 0 || y < 0 || x >= fd.W || y >= fd.H) return null;
  const id = fd.fits.fit_ids[Math.floor(y) * fd.W + Math.floor(x)];
  return id ? fd.fitEntries[id - 1] : null;
}
async function rejectFit() {  // K: reject the selected fit (or the one under the pointer); again: take it back
  const fd = state.cur; if (!fd || !fd.fits || fd.fits.header.status !== 'ready') { setSaveState('no fits on this frame', 'error'); return; }
  let e = state.sel >= 0 ? fd.entries[state.sel] : null;
  if (e && e.src === 'u' && e.fromFit >= 0) e = fd.fitEntries[e.fromFit];
  if (!e || e.src !== 'f') e = hover ? fitAt(fd, hover.x, hover.y) : null;
  if (!e) { setSaveState('K: select a fit (or point at one) first', 'error'); return; }
  const r = await fetch(`/api/frames/${fd.index}/fits/${e.fit}`, { method: 'PUT', headers: { 'Content-Type': 'application/json' },
                                                                  body: JSON.stringify({ rejected: !e.rejected }) });
  if (!r.ok) { showError(`fit ${e.fit}: HTTP ${r.status}`); return; }
  const was = e.rejected;
  applyFits(fd, parseFitsBundle(await r.arrayBuffer()));
  const now = fd.fitEntries[e.fit];
  setSaveState(was ? `fit #${e.id} taken back` : `fit #${e.id} rejected: ${now ? now.proposed : 0} of its ${e.n} px ` +
    `proposed again (the others lie within ${fd.fits.header.k} × Err of another known surface)`, 'saved');
  const k = fd.entries.findIndex((x) => x.src === 'u' && x.fromFit === e.fit);
  if (!was && k >= 0) select(k, { zoom: true });
  else { const j = fd.entries.findIndex((x) => x.src === 'f' && x.fit === e.fit); if (j >= 0) select(j, { zoom: false }); }
}
async function seedFit(fd, x, y) {  // Ctrl+click: fit the part again around (x, y), on its unexplained pixels
  if (!fd.fits || fd.fits.header.status !== 'ready') { setSaveState('no fits on this frame to add to', 'error'); return; }
  x = Math.floor(x); y = Math.floor(y);
  if (x < 0 || y < 0 || x >= fd.W || y >= fd.H) return;
  setSaveState('fitting at the click…', 'saving');
  const r = await fetch(`/api/frames/${fd.index}/fits/seed`, { method: 'POST', headers: { 'Content-Type': 'application/json' },
                                                              body: JSON.stringify({ x, y }) });
  if (!r.ok) { showError(`seed: HTTP ${r.status}`); return; }
  const n = +r.headers.get('X-Zcut-Seeded');
  applyFits(fd, parseFitsBundle(await r.arrayBuffer()));
  setSaveState(n ? `seeded ${n} fit${n > 1 ? 's' : ''}` : 'no instance found at the click', n ? 'saved' : 'error');
  if (n) { const j = fd.entries.findIndex((e) => e.src === 'f' && e.fit === fd.fitEntries.length - 1); if (j >= 0) select(j, { zoom: false }); }
}
function fitPoints(fd, nb, ox, oy, oz, sel) {  // the fits near the neighbourhood, posed model samples (view coordinates)
  const f = fd.fits, pos = [], col = [];
  if (!f || f.header.status !== 'ready' || !f.header.model_points) return { pos, col };
  for (const e of fd.fitEntries) {
    if (e.x1 < nb.x0 || e.x0 > nb.x1 || e.y1 < nb.y0 || e.y0 > nb.y1) continue;
    const P = e.pose, c = e.rejected ? [255, 0, 255] : e === sel ? [255, 255, 255] : [150, 190, 255];
    for (const m of f.header.model_points) {
      const x = P[0] * m[0] + P[1] * m[1] + P[2] * m[2] + P[3], y = P[4] * m[0] + P[5] * m[1] + P[6] * m[2] + P[7];
      const z = P[8] * m[0] + P[9] * m[1] + P[10] * m[2] + P[11];
      pos.push(x - 1000 * ox, -(y - 1000 * oy), -(z - 1000 * oz)); col.push(...c);
    }
  }
  return { pos, col };
}

// ------------------------------------------------------------------ navigation
let navToken = 0;
async function goTo(index, t0 = performance.now()) {
  if (index === undefined || index === null) return;
  if (!state.frames.some((f) => f.index === index)) return;
  const my = ++navToken;
  state.target = index;
  if (state.cur && state.cur.index !== index) {  // saved once the next frame is on screen
    const left = state.cur;
    requestAnimationFrame(() => setTimeout(() => saveNow(left), 0));
  }
  if (!state.cur || state.cur.index !== index) $('frameinfo').textContent = `→ frame ${index} …`;
  let fd;
  try { fd = await loadFrame(index); } catch (e) { showError(String(e)); return; }
  if (my !== navToken) return;
  const t1 = performance.now();
  state.cur = fd;
  state.sel = -1; state.profile = null; state.conflictView = 'mine';
  // the canvas first (its size read before the page's text changes: one layout, not two), then the rest
  if (!sameFlags(fd.ovFlags, flags())) renderOverlay();
  fit(false);  // a new frame starts at the overview
  applyHeld(fd);  // what arrived while the pointer was over its list
  refreshList(fd, false, false);  // the candidates (for the markers), their rows below
  draw();
  const t2 = performance.now();
  if (view3d) view3d.clear();
  $('v3info').textContent = 'Tab: the next candidate, its profile and 3D view';
  showConflict(fd);
  showFrameWarning(fd);
  if (state.riseMm === null) { $('rise').value = riseThreshold(fd); $('riseval').textContent = riseThreshold(fd).toFixed(1); }
  renderList();
  $('candlist').scrollTop = 0;
  loadProposals(fd);
  if (!fd.fits || fd.fits.header.status === 'waiting' || fd.fits.header.status === 'fitting') loadFits(fd);
  showFitInfo(fd);
  drawProfile();
  updateInfo();
  const t3 = performance.now();
  requestAnimationFrame(() => {
    window.zcut.switchTimes.push(performance.now() - t0);
    window.zcut.switchParts.push({ index, wait: t1 - t0, canvas: t2 - t1, page: t3 - t2, paint: performance.now() - t3 });
    window.zcut.shown = index;
  });
  history.replaceState(null, '', `/#${index}`);
  evict(index);
  (async () => {  // prefetch the neighbours in list order, one at a time, the next one first
    const k = state.order.indexOf(index);
    for (const d of [1, -1, 2, -2]) {
      const j = state.order[k + d];
      if (my !== navToken) return;
      if (j !== undefined) { try { await loadFrame(j); } catch (e) { /* shown on use */ } }
    }
  })();
}

function step(d, t0) {  // navigation keys queue: each press moves the target one frame further
  if (!state.order.length) return;
  const from = state.target !== null ? state.target : state.cur ? state.cur.index : state.order[0];
  const k = state.order.indexOf(from);
  const j = Math.max(0, Math.min(state.order.length - 1, k + d));
  if (state.order[j] !== from || !state.cur || state.cur.index !== from) goTo(state.order[j], t0);
}

function frameRow(index) { return state.frames.find((f) => f.index === index); }

function updateStatus() {
  const fd = state.cur; if (!fd) return;
  const el = $('status');
  el.title = COUNTS_TITLE;
  if (fd.nR >= fd.nValid) { el.textContent = 'frame reviewed ✓'; el.className = 'reviewed'; }
  else if (fd.nR > 0) {
    el.textContent = shadeUnreviewed(fd) ? `reviewed except ${fd.nValid - fd.nR} px (shaded)`
      : `not reviewed yet · ${countsText(fd)} (Enter: reviewed)`;
    el.className = 'partial';
  } else { el.textContent = `not reviewed · ${countsText(fd)}`; el.className = 'todo'; }
}

function updateInfo() {
  const fd = state.cur;
  if (fd) $('frameinfo').textContent = `frame ${fd.index} (${state.order.indexOf(fd.index) + 1} of ${state.order.length})  ` +
    `z-cut ${fd.header.n_zcut} · SOR ${fd.header.n_sor} clusters  rev ${fd.rev}`;
  const reviewed = state.frames.filter((f) => f.reviewed).length;
  $('progress').textContent = `reviewed ${reviewed} / ${state.total}` + (state.done ? '' : ' (preparing…)');
  updateStatus();
  const ol = $('framelist');
  if (ol.children.length !== state.order.length || ol.dataset.order !== state.orderBy) {
    ol.replaceChildren(...state.order.map((i) => {
      const li = document.createElement('li');
      li.dataset.index = i;
      li.onclick = () => { window.zcut.inputs++; goTo(i); };
      return li;
    }));
    ol.dataset.order = state.orderBy;
  }
  for (const li of ol.children) {
    const f = frameRow(+li.dataset.index);
    if (!f) continue;
    const mark = f.reviewed ? '✓' : f.revision ? '◐' : '';
    const cur = fd && f.index === fd.index && fd.entries ? groupCounts(fd) : null;  // the panel's counts, unsaved edits included
    const decided = cur ? cur.decided : f.decided;
    li.title = `frame ${f.index}: ${f.n_groups} review groups, ${decided} decided, ${f.n_outliers} outlier px labelled` +
      (f.uncertain === null ? '' : `, the assistant is unsure of ${f.uncertain}`) + (f.bin_stages ? '' : ' (no bin stages)');
    li.innerHTML = `<b>${f.index}</b><span>${f.n_groups} groups</span><span>${decided} dec.</span>` +
      `<span>${f.n_outliers} px</span><span class="dis">${f.uncertain === null ? '' : '?' + f.uncertain}</span><span class="mk">${mark}</span>`;
    li.classList.toggle('rev', !!f.reviewed);
    li.classList.toggle('cur', !!fd && f.index === fd.index);
  }
}

function setOrder(by) {
  state.orderBy = by;
  const rows = state.frames.slice();
  if (by === 'disagreement') rows.sort((a, b) => b.disagreement - a.disagreement || a.index - b.index);
  if (by === 'uncertainty') rows.sort((a, b) => (b.uncertain ?? -1) - (a.uncertain ?? -1) || a.index - b.index);
  state.order = rows.map((f) => f.index);
  updateInfo();
}

async function refreshFrames({ again = false } = {}) {  // again: poll while frames are being prepared
  const r = await fetch('/api/frames');
  if (r.ok) {
    const j = await r.json();
    state.frames = j.frames; state.total = j.total; state.done = j.done;
    setOrder(state.orderBy);
    if (j.error) showError(`preparing frames stopped: ${j.error}`);
  }
  if (again && !state.done) setTimeout(() => refreshFrames({ again: true }), 1000);
}

async function refreshSession() {
  try {
    const r = await fetchRetry('/api/session');
    if (r.status === 403) { sessionLost(); throw new Error('the page session ended'); }
    const s = await r.json();
    const b = $('banner');
    if (s.other_servers.length) {
      b.textContent = `Another server uses this label store: ${s.other_servers.join('; ')}. ` +
        'Edits from both are kept; the same annotator on both will meet conflicts.';
      b.hidden = false;
    } else b.hidden = true;
    return s;
  } finally { setTimeout(refreshSession, 10000); }
}

function showFocus(f) {  // zcut annotate --disagreement: what this review is, for as long as the page is open
  const el = $('focusbar');
  if (!f) { el.hidden = true; return; }
  const px = (n) => `${n} pixel${n === 1 ? '' : 's'}`;
  el.textContent = `Disagreement review (zcut compare ${f.folder}): the groups are only the ${px(f.pixels)} ` +
    `where A (${f.a}) and B (${f.b}) disagree — ${f.only_a} removed by A alone, ${f.only_b} by B alone — on ` +
    `${f.frames} of the ${f.compared} compared frames. Only these pixels can change the comparison's verdict; ` +
    'label them, then score both with zcut compare --labels.';
  el.hidden = false;
}

function nextUnreviewed() {
  const k = state.cur ? state.order.indexOf(state.cur.index) : -1;
  const rows = state.order.map(frameRow);
  const f = rows.slice(k + 1).find((g) => g && !g.reviewed) || rows.find((g) => g && !g.reviewed);
  if (f) goTo(f.index);
}

// ------------------------------------------------------------------ editing
let action = null;  // {x0, y0, x1, y1} dirty box of the running edit
function beginAction() { action = { x0: Infinity, y0: Infinity, x1: -Infinity, y1: -Infinity }; }
function touch(x0, y0, x1, y1) {
  action.x0 = Math.min(action.x0, x0); action.y0 = Math.min(action.y0, y0);
  action.x1 = Math.max(action.x1, x1); action.y1 = Math.max(action.y1, y1);
}
function endAction(fd) {  // one undo step: the pixels the edit changed, with their old and new values
  const a = action; action = null;
  if (!a || a.x1 < a.x0) return;
  const W = fd.W;
  const x0 = Math.max(0, Math.floor(a.x0)), y0 = Math.max(0, Math.floor(a.y0));
  const x1 = Math.min(fd.W, Math.ceil(a.x1)), y1 = Math.min(fd.H, Math.ceil(a.y1));
  const idx = [], oL = [], oR = [];
  for (let y = y0; y < y1; y++) for (let i = y * W + x0, e = y * W + x1; i < e; i++) {
    if (fd.L[i] !== fd.committedL[i] || fd.R[i] !== fd.committedR[i]) {
      idx.push(i); oL.push(fd.committedL[i]); oR.push(fd.committedR[i]);
      fd.committedL[i] = fd.L[i]; fd.committedR[i] = fd.R[i];
    }
  }
  if (!idx.length) return;
  const rec = { idx: Int32Array.from(idx), oL: Uint8Array.from(oL), oR: Uint8Array.from(oR), box: [x0, y0, x1, y1] };
  rec.nL = Uint8Array.from(rec.idx, (i) => fd.L[i]); rec.nR = Uint8Array.from(rec.idx, (i) => fd.R[i]);
  fd.undo.push(rec); if (fd.undo.length > 200) fd.undo.shift();
  fd.redo = [];
  afterEdit(fd, rec.box);
}

function afterEdit(fd, box) {
  countR(fd);
  if (box) renderOverlay(...box); else renderOverlay();
  fd.labelEntries = labelComponents(fd);
  refreshList(fd, true);
  requestDraw();
  if (state.profile) drawProfile();
  scheduleSave(fd);
}

function applyRecord(fd, rec, forward) {
  const vL = forward ? rec.nL : rec.oL, vR = forward ? rec.nR : rec.oR;
  if (rec.full) {  // the "reviewed" mark: R only
    if (forward) fd.R.set(fd.valid); else fd.R.set(rec.oR);
    fd.committedR.set(fd.R);
  } else for (let k = 0; k < rec.idx.length; k++) {
    const i = rec.idx[k];
    fd.L[i] = fd.committedL[i] = vL[k]; fd.R[i] = fd.committedR[i] = vR[k];
  }
  afterEdit(fd, null);
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
function riseAt(fd, i) { return fd.rise[i] * (fd.header.rise_step_mm || 0.1); }
function riseThreshold(fd) { return state.riseMm !== null ? state.riseMm : Math.max(0.1, fd.header.threshold_mm || 0.5); }
// The residual brush works inside one group: the one under the stroke's first pixel (0: the pixels no group
// holds). It never takes a pixel of another group or outside, and when the stroke ends the group's pixels it
// left are reviewed as not outliers, so the group is decided and no later Shift+A / Shift+R overwrites it.
let rbrushGroup = -1;
function setPixel(fd, i, mode) {  // every decision reviews the pixel: L ⊆ R
  if (!fd.valid[i]) return;
  if (mode === 'radd' || mode === 'rerase') {  // the residual brush: only pixels standing above the threshold
    if (rbrushGroup >= 0 && fd.gIds[i] !== rbrushGroup) return;
    if (riseAt(fd, i) < riseThreshold(fd)) return;
    mode = mode === 'radd' ? 'add' : 'erase';
  }
  if (mode === 'fill-add' || mode === 'fill-erase') {  // a bulk decision (fillEntry): a reviewed pixel keeps its decision
    if (fd.R[i]) return;
    mode = mode === 'fill-add' ? 'add' : 'erase';
  }
  if (mode === 'add') { fd.L[i] = 1; fd.R[i] = 1; }
  else if (mode === 'erase') { fd.L[i] = 0; fd.R[i] = 1; }
  else if (mode === 'unreview') { fd.L[i] = 0; fd.R[i] = 0; }
}
function paintLine(fd, a, b, mode) {
  const d = Math.hypot(b.x - a.x, b.y - a.y), stepLen = Math.max(1, state.brush / 3);
  const n = Math.max(1, Math.ceil(d / stepLen));
  for (let k = 1; k <= n; k++) paintDisc(fd, a.x + (b.x - a.x) * k / n, a.y + (b.y - a.y) * k / n, state.brush, mode);
}

function clickCluster(fd, x, y, preferSor) {  // toggle the cluster under the pointer, select its entry
  x = Math.floor(x); y = Math.floor(y);
  if (x < 0 || y < 0 || x >= fd.W || y >= fd.H) return false;
  const i = y * fd.W + x;
  if (fd.gIds[i]) return toggleEntry(fd, fd.base.find((b) => b.id === fd.gIds[i]));  // a review group, as a whole
  const sOk = fd.sIds[i] !== 0 && state.showS;
  const order = preferSor ? [['s', sOk], ['z', fd.zIds[i] !== 0 && state.showZ]] : [['z', fd.zIds[i] !== 0 && state.showZ], ['s', sOk]];
  let src = null;
  for (const [s, ok] of order) if (ok) { src = s; break; }
  let e = null;
  if (src) {
    const id = src === 'z' ? fd.zIds[i] : fd.sIds[i];
    e = fd.base.find((b) => b.src === src && b.id === id);
    if (!e) {  // a SOR cluster too small to be listed
      const start = src === 'z' ? fd.zStart : fd.sStart, pix = src === 'z' ? fd.zPix : fd.sPix;
      const p = pix.subarray(start[id], start[id + 1]);
      let x0 = fd.W, y0 = fd.H, x1 = 0, y1 = 0;
      for (const j of p) { const px = j % fd.W, py = (j / fd.W) | 0; x0 = Math.min(x0, px); x1 = Math.max(x1, px); y0 = Math.min(y0, py); y1 = Math.max(y1, py); }
      e = { src, id, n: p.length, pix: p, x0, y0, x1: x1 + 1, y1: y1 + 1 };
    }
  } else e = fd.labelEntries.find((l) => l.pix.includes(i));
  if (!e) return false;
  return toggleEntry(fd, e);
}

function toggleEntry(fd, e) {  // accept the entry's pixels, or take them back if accepted; select its row
  const accept = entryState(fd, e) !== 'accepted';
  beginAction(fd);
  for (const j of e.pix) setPixel(fd, j, accept ? 'add' : 'erase');
  touch(e.x0, e.y0, e.x1, e.y1);
  endAction(fd);
  const k = fd.entries.indexOf(e);
  if (k >= 0) select(k, { zoom: false });
  return true;
}

function fillPolygon(fd, pts, mode, only = null) {  // only(i): which pixels inside may change
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
    const i = (yy + y0) * fd.W + xx + x0;
    if (a[(yy * w + xx) * 4 + 3] >= 128 && (!only || only(i))) setPixel(fd, i, mode);
  }
  touch(x0, y0, x1, y1);
}

// The height-gap wand: from the clicked pixel (or the nearest one within 6 px standing above the
// threshold) grow over the 8-connected pixels that stand above the surface around them by at least
// the threshold (the 'rise' the server computed); at most 200,000 pixels.
function wand(fd, x, y, mode) {
  const W = fd.W, H = fd.H, thr = riseThreshold(fd);
  x = Math.floor(x); y = Math.floor(y);
  let seed = -1, best = Infinity;
  for (let dy = -6; dy <= 6; dy++) for (let dx = -6; dx <= 6; dx++) {
    const xx = x + dx, yy = y + dy;
    if (xx < 0 || yy < 0 || xx >= W || yy >= H) continue;
    const i = yy * W + xx, d = dx * dx + dy * dy;
    if (riseAt(fd, i) >= thr && d < best) { best = d; seed = i; }
  }
  if (seed < 0) { setSaveState(`wand: nothing stands ${thr.toFixed(1)} mm above the surface here`, 'error'); return; }
  const seen = new Uint8Array(W * H), stack = [seed], got = [];
  seen[seed] = 1;
  let x0 = W, y0 = H, x1 = 0, y1 = 0;
  while (stack.length && got.length < 200000) {
    const j = stack.pop(); got.push(j);
    const jx = j % W, jy = (j / W) | 0;
    x0 = Math.min(x0, jx); x1 = Math.max(x1, jx); y0 = Math.min(y0, jy); y1 = Math.max(y1, jy);
    for (let dy = -1; dy <= 1; dy++) for (let dx = -1; dx <= 1; dx++) {
      const xx = jx + dx, yy = jy + dy;
      if (xx < 0 || yy < 0 || xx >= W || yy >= H) continue;
      const k = yy * W + xx;
      if (!seen[k] && riseAt(fd, k) >= thr) { seen[k] = 1; stack.push(k); }
    }
  }
  beginAction(fd);
  for (const j of got) setPixel(fd, j, mode);
  touch(x0, y0, x1 + 1, y1 + 1);
  endAction(fd);
  setSaveState(`wand: ${got.length} px standing ≥ ${thr.toFixed(1)} mm above the surface ${mode === 'add' ? 'labelled' : 'cleared'}`, 'saved');
}

function markReviewed(fd) {  // the explicit "reviewed": every valid pixel reviewed, L kept
  if (fd.nR >= fd.nValid) return;
  const rec = { full: true, oR: fd.R.slice() };  // undo: R back (L does not change)
  fd.R.set(fd.valid); fd.committedR.set(fd.R); fd.nR = fd.nValid;
  fd.undo.push(rec); if (fd.undo.length > 200) fd.undo.shift();
  fd.redo = [];
  // with every pixel reviewed nothing is shaded: the overlay shows what it showed (unless it shaded)
  if (fd.ovShade) renderOverlay(); else fd.ovShade = true;
  refreshList(fd, true);
  requestDraw();
  scheduleSave(fd);
}
function markReviewedAndNext(t0) {
  const fd = state.cur; if (!fd) return;
  markReviewed(fd);
  step(1, t0);  // (the frame left is saved right after the next one is drawn)
}

// ------------------------------------------------------------------ saving
function setSaveState(text, cls) { const s = $('savestate'); s.textContent = text; s.className = 'state ' + cls; }
function showError(msg) { window.zcut.errors.push(msg); setSaveState(msg, 'error'); }

// Unsaved edits survive the page and the server: each dirty frame's label body is kept in this
// browser's localStorage (per log, annotator and frame) until the server acknowledges it.
function pendingKey(index) { return `zcut:${state.sha256}:${state.annotator}:${index}`; }
function keepPending(fd) {
  if (!state.sha256) return;
  try { localStorage.setItem(pendingKey(fd.index), labelBody(fd, fd.seq)); } catch (e) { /* quota: the server has it soon */ }
}
function dropPending(fd) { if (state.sha256 && !fd.dirty) localStorage.removeItem(pendingKey(fd.index)); }
function decodeRuns(b64, n) {
  const bin = atob(b64), bytes = new Uint8Array(bin.length);
  for (let i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
  const runs = new Uint32Array(bytes.buffer), out = new Uint8Array(n);
  let p = 0;
  for (let k = 0; k < runs.length; k++) { const e = p + runs[k]; if (k & 1) out.fill(1, p, e); p = e; }
  return p === n ? out : null;
}
function restorePending(fd) {  // a frame's edits kept in the browser come back when it is loaded
  if (!state.sha256) return;
  const raw = localStorage.getItem(pendingKey(fd.index));
  if (!raw) return;
  try {
    const b = JSON.parse(raw), n = fd.W * fd.H;
    const L = decodeRuns(b.outliers_runs, n), U = decodeRuns(b.unreviewed_runs, n);
    if (!L || !U || b.width !== fd.W || b.height !== fd.H) return;
    if (fd.rev > b.base_revision) {  // the store moved on: if it holds exactly the kept edit, that edit arrived
      let same = true;  // (e.g. sent as the page went away, its acknowledgement lost with the page)
      for (let i = 0; i < n && same; i++) same = fd.L[i] === L[i] && fd.R[i] === (fd.valid[i] && !U[i] ? 1 : 0);
      if (same) { localStorage.removeItem(pendingKey(fd.index)); return; }
    }
    fd.L.set(L); for (let i = 0; i < n; i++) fd.R[i] = fd.valid[i] && !U[i] ? 1 : 0;
    fd.committedL.set(fd.L); fd.committedR.set(fd.R);
    fd.rev = b.base_revision; fd.dirty = true; countR(fd);
    window.zcut.restored = (window.zcut.restored || []).concat([fd.index]);
    setTimeout(() => saveNow(fd), 0);
  } catch (e) { /* a damaged entry: left alone */ }
}
function pendingIndices() {
  const pre = `zcut:${state.sha256}:${state.annotator}:`, out = [];
  for (let k = 0; k < localStorage.length; k++) { const key = localStorage.key(k); if (key.startsWith(pre)) out.push(+key.slice(pre.length)); }
  return out.sort((a, b) => a - b);
}
function sessionLost() {  // the server answered 403 to a save: it does not know this page any more
  if (state.sessionLost) return;
  state.sessionLost = true;
  const frames = [...new Set([...pendingIndices(), ...[...loaded.values()].filter((f) => f.dirty).map((f) => f.index)])];
  $('lostmsg').textContent = `The server no longer knows this page (it was restarted, or this page's session ended). ` +
    `Your unsaved edits of frame(s) ${frames.join(', ') || '—'} are kept in this browser. Start zcut annotate again ` +
    `on the same port (--port ${location.port}) and paste the URL it prints here; the edits are sent once it answers.`;
  $('lost').hidden = false;
}
async function reconnect(url) {
  const m = /[?&]token=([^&#\s]+)/.exec(url.trim()), token = m ? m[1] : url.trim();
  const r = await fetch(`/?token=${encodeURIComponent(token)}`, { credentials: 'same-origin' });
  if (!r.ok) { $('lostmsg').textContent = `That token was refused (HTTP ${r.status}): paste the URL the new server printed.`; return; }
  state.sessionLost = false; $('lost').hidden = true;
  if (state.mode === 'choose' && state.annotator) {
    await fetch('/api/annotator', { method: 'POST', headers: { 'Content-Type': 'application/json' },
                                    body: JSON.stringify({ name: state.annotator }) });
  }
  await refreshFrames();
  flushPending();
}
async function flushPending() {  // the edits kept in the browser: loaded frames save, the others are sent as kept
  for (const fd of loaded.values()) if (fd.dirty && !fd.conflict) saveNow(fd);
  for (const i of pendingIndices()) {
    if (loaded.has(i)) continue;
    const body = localStorage.getItem(pendingKey(i));
    const r = await fetch(`/api/frames/${i}/label`, { method: 'PUT', headers: { 'Content-Type': 'application/json' }, body });
    if (r.ok) { localStorage.removeItem(pendingKey(i)); window.zcut.acks.push({ index: i, flushed: true }); }
    else if (r.status === 403) { sessionLost(); return; }
    else if (r.status === 409) setSaveState(`frame ${i}: the edits kept in this browser meet a newer revision: open frame ${i} to merge`, 'error');
  }
  refreshFrames();
}

function scheduleSave(fd) {
  fd.dirty = true;
  keepPending(fd);
  setSaveState('unsaved', 'saving');
  clearTimeout(fd.saveTimer);
  fd.saveTimer = setTimeout(() => saveNow(fd), 250);
}

function runsB64(mask, base) {  // uint32 runs (false, true, ...) of mask (or of base ∧ ¬mask), base64
  const runs = [];
  let cur = 0, len = 0;
  for (let i = 0; i < mask.length; i++) {
    const v = base ? (base[i] && !mask[i] ? 1 : 0) : mask[i];
    if (v === cur) { len++; continue; }
    runs.push(len); cur = v; len = 1;
  }
  runs.push(len);
  const bytes = new Uint8Array(Uint32Array.from(runs).buffer);
  let s = '';
  for (let i = 0; i < bytes.length; i += 0x8000) s += String.fromCharCode.apply(null, bytes.subarray(i, i + 0x8000));
  return btoa(s);
}
function labelBody(fd, seq) {
  return JSON.stringify({ base_revision: fd.rev, height: fd.H, width: fd.W, client: CLIENT, seq,
                          outliers_runs: runsB64(fd.L, null), unreviewed_runs: runsB64(fd.R, fd.valid) });
}

async function saveNow(fd, { keepalive = false } = {}) {
  clearTimeout(fd.saveTimer);
  if (!fd.dirty || fd.conflict) return;
  if (fd.saving && !keepalive) { fd.pendingSave = true; return; }
  const body = labelBody(fd, ++fd.seq);
  if (keepalive && body.length > KEEPALIVE_MAX) return;  // too big to outlive the page: beforeunload asks
  fd.saving = true; fd.dirty = false;
  setSaveState('saving…', 'saving');
  let retry = false;
  try {
    const resp = await fetch(`/api/frames/${fd.index}/label`, { method: 'PUT', keepalive,
      headers: { 'Content-Type': 'application/json' }, body });
    if (resp.ok) {
      const j = await resp.json();
      fd.rev = Math.max(fd.rev, j.revision);
      dropPending(fd);
      window.zcut.acks.push({ index: fd.index, revision: j.revision, n_outliers: j.n_outliers, annotator: j.annotator,
                              superseded: j.superseded });
      const f = frameRow(fd.index);
      if (f && !j.superseded) Object.assign(f, { reviewed: j.reviewed, revision: j.revision, n_outliers: j.n_outliers,
                                                 decided: j.decided, accepted: j.accepted });
      setSaveState(`saved (frame ${fd.index} rev ${j.revision})`, 'saved');
      updateInfo();
    } else if (resp.status === 409) {
      const j = await resp.json();
      fd.dirty = true;
      await openConflict(fd, j.latest);
    } else {
      const t = await resp.text();
      fd.dirty = true;
      if (resp.status === 507) {  // the store's disk is full: nothing was written; the edit stays here
        showError(`frame ${fd.index} not saved: the label store's disk is full. Your edits stay on this page ` +
                  'and are sent again every few seconds; free some space.');
        setSaveState('not saved: disk full (retrying)', 'saving');
      } else showError(`save failed (HTTP ${resp.status}): ${t.slice(0, 200)}`);
      retry = resp.status >= 500;
      if (resp.status === 403) { keepPending(fd); sessionLost(); }
    }
  } catch (e) {
    fd.dirty = true; retry = true;
    keepPending(fd);
    showError(`save failed (the server does not answer; the edit is kept in this browser): ${e}`);
  } finally {
    fd.saving = false;
  }
  if (state.sessionLost) return;  // waits for reconnect()
  if (fd.pendingSave || (fd.dirty && retry)) {
    fd.pendingSave = false;
    if (retry) setTimeout(() => saveNow(fd), 2000); else saveNow(fd);
  }
}

// leaving the page (reload, close, another site): what is not saved goes out as keepalive requests,
// which the browser finishes after the page is gone
function flushOnLeave() {
  for (const fd of loaded.values()) if (fd.dirty && !fd.conflict) saveNow(fd, { keepalive: true });
}

// ------------------------------------------------------------------ conflicts: both versions, merge
async function openConflict(fd, latest) {
  let theirs;
  try { theirs = await call({ type: 'label', index: fd.index, W: fd.W, H: fd.H, nValid: fd.nValid }); } catch (e) { showError(String(e)); return; }
  fd.conflict = { latest: theirs.rev, theirs };
  showError(`frame ${fd.index} was saved elsewhere meanwhile (revision ${latest}): choose how to merge`);
  if (fd === state.cur) { showConflict(fd); renderOverlay(); requestDraw(); }
}
function showConflict(fd) {
  const box = $('conflict'), c = fd && fd.conflict;
  box.hidden = !c;
  if (!c) return;
  let mine = 0, theirs = 0, differ = 0, mineR = 0, theirsR = 0;
  for (let i = 0; i < fd.L.length; i++) {
    mine += fd.L[i]; theirs += c.theirs.L[i]; differ += fd.L[i] !== c.theirs.L[i]; mineR += fd.R[i]; theirsR += c.theirs.R[i];
  }
  $('conflictinfo').textContent = `Frame ${fd.index} was saved elsewhere (revision ${c.latest}). Mine: ${mine} outlier px, ` +
    `${mineR} reviewed px. Theirs: ${theirs} outlier px, ${theirsR} reviewed px. They differ at ${differ} px.`;
  for (const b of document.querySelectorAll('#conflict [data-view]')) b.classList.toggle('active', b.dataset.view === state.conflictView);
}
function setConflictView(v) {
  state.conflictView = v; showConflict(state.cur); renderOverlay();
  const fd = state.cur;
  if (v !== 'mine' && fd && fd.conflict) {  // look at where the versions differ
    const t = fd.conflict.theirs.L;
    let x0 = fd.W, y0 = fd.H, x1 = -1, y1 = -1;
    for (let i = 0; i < t.length; i++) if (t[i] !== fd.L[i]) {
      const x = i % fd.W, y = (i / fd.W) | 0;
      x0 = Math.min(x0, x); x1 = Math.max(x1, x); y0 = Math.min(y0, y); y1 = Math.max(y1, y);
    }
    if (x1 >= 0) zoomToBox(x0, y0, x1 + 1, y1 + 1);
  }
  requestDraw();
}
function resolveConflict(how) {
  const fd = state.cur; if (!fd || !fd.conflict) return;
  const t = fd.conflict.theirs;
  if (how === 'union') for (let i = 0; i < fd.L.length; i++) { fd.L[i] |= t.L[i]; fd.R[i] |= t.R[i]; }
  else if (how === 'theirs') { fd.L.set(t.L); fd.R.set(t.R); }
  fd.rev = fd.conflict.latest; fd.conflict = null; state.conflictView = 'mine';
  fd.committedL.set(fd.L); fd.committedR.set(fd.R); fd.undo = []; fd.redo = [];
  showConflict(fd);
  countR(fd); renderOverlay(); fd.labelEntries = labelComponents(fd); refreshList(fd, true); requestDraw();
  if (how === 'theirs') { fd.dirty = false; setSaveState(`frame ${fd.index}: theirs kept (rev ${fd.rev})`, 'saved'); updateInfo(); }
  else { fd.dirty = true; saveNow(fd); }
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
window.zcut.gapText = (gap) => gapText(gap === null ? NaN : gap);
window.zcut.GAP_UNKNOWN = GAP_UNKNOWN;
window.zcut.state = () => {
  const fd = state.cur; if (!fd) return null;
  let nL = 0, nR = 0;
  for (let i = 0; i < fd.L.length; i++) { nL += fd.L[i]; nR += fd.R[i]; }
  const r = canvas.getBoundingClientRect();
  const e = state.sel >= 0 ? fd.entries[state.sel] : null;
  return { index: fd.index, rev: fd.rev, dirty: fd.dirty, saving: fd.saving, conflict: fd.conflict ? fd.conflict.latest : 0,
           nL, nR, nValid: fd.nValid, W: fd.W, H: fd.H, tool: state.tool, zoom: state.zoom, annotator: state.annotator,
           brush: state.brush, view: state.showH ? 'height' : 'rgb', overlay: state.showOv, progress: $('progress').textContent,
           status: $('status').textContent, target: state.target, sel: state.sel, entries: fd.entries.length,
           states: fd.states ? fd.states.slice() : [], selected: e ? { src: e.src, id: e.id, n: e.n, cx: e.cx, cy: e.cy,
             gap: e.gap, x0: e.x0, y0: e.y0, x1: e.x1, y1: e.y1, screen: toScreen(e.cx, e.cy) } : null,
           viewport: { x: r.left, y: r.top, width: r.width, height: r.height }, order: state.order.slice(),
           profile: state.profile ? { x0: state.profile.x0, y0: state.profile.y0, x1: state.profile.x1, y1: state.profile.y1 } : null };
};
window.zcut.labelOutside = (id) => {  // outlier pixels (L) not in review group id
  const fd = state.cur; let n = 0;
  for (let i = 0; i < fd.L.length; i++) if (fd.L[i] && fd.gIds[i] !== id) n++;
  return n;
};
window.zcut.profileAxis = () => drawProfile.axis || null;
window.zcut.pixelState = (x, y) => {  // the decision on image pixel (x, y) and the review group it is in (0: none)
  const fd = state.cur, i = y * fd.W + x;
  return { L: fd.L[i], R: fd.R[i], group: fd.gIds[i], valid: fd.valid[i] };
};
window.zcut.entries = () => {
  const fd = state.cur; if (!fd) return [];
  return fd.entries.map((e, k) => ({ src: e.src, id: e.id, n: e.n, cx: e.cx, cy: e.cy, gap: e.gap, both: e.both,
                                     err: e.err, dist: e.dist, fit: e.fit, fromFit: e.fromFit, rejected: e.rejected,
                                     source: e.source, also: e.also, p: propP(fd, e), confident: !!confident(fd, e),
                                     state: (fd.states || [])[k] }));
};
window.zcut.proposals = () => {
  const fd = state.cur; if (!fd || !fd.prop) return null;
  const { out, inl } = proposalPlan(fd);
  return { version: fd.prop.version, prefill: fd.prop.prefill, why_not: fd.prop.why_not, message: fd.prop.message,
           n: fd.prop.p.length, out: out.map((e) => e.id), inl: inl.map((e) => e.id), model: fd.prop.model };
};
window.zcut.readout = () => $('readout').textContent;
window.zcut.look = (x, y, zoom) => {  // centre image pixel (x, y) at a zoom, drawn now (the tests read the canvas)
  state.zoom = zoom; state.px = canvas.clientWidth / 2 - (x + 0.5) * zoom; state.py = canvas.clientHeight / 2 - (y + 0.5) * zoom;
  draw();
};
window.zcut.canvasPixel = (x, y) => {  // [r, g, b, a] the view shows inside image pixel (x, y) (off its centre:
  const dpr = window.devicePixelRatio || 1, s = toScreen(x + 0.3, y + 0.3);  // a profile line runs through centres)
  return Array.from(ctx.getImageData(Math.floor(s.x * dpr), Math.floor(s.y * dpr), 1, 1).data);
};
window.zcut.overlayColour = (name) => {  // an overlay colour as [r, g, b, a]
  const c = { U: COL_U, UR: COL_UR, L: COL_L, G: COL_G, GR: COL_GR }[name];
  return [c & 255, (c >>> 8) & 255, (c >>> 16) & 255, c >>> 24];
};
window.zcut.markers = () => drawMarkers.drawn;
window.zcut.markerBoxes = () => {  // the boxes of the entries that have a marker (not the proposals, not the fits)
  const fd = state.cur; if (!fd) return [];
  return fd.entries.filter((e) => e.src !== 'u' && e.src !== 'f').map((e) => [e.x0, e.y0, e.x1, e.y1]);
};
window.zcut.sections = () => [...document.querySelectorAll('#candlist .sect')].map((h) => h.firstChild.textContent);
window.zcut.fits = () => {
  const fd = state.cur; if (!fd || !fd.fits) return null;
  const h = fd.fits.header;
  return { status: h.status, message: h.message, n_fits: h.n_fits || 0, n_rejected: h.n_rejected || 0,
           n_proposals: h.n_proposals || 0, info: $('fitinfo').textContent,
           fits: (fd.fitEntries || []).map((e) => ({ fit: e.fit, n: e.n, err: e.err, rejected: e.rejected, seeded: e.seeded,
                                                     proposed: e.proposed, cx: e.cx, cy: e.cy })),
           proposals: (fd.propEntries || []).map((e) => ({ id: e.id, n: e.n, dist: e.dist, fromFit: e.fromFit, cx: e.cx, cy: e.cy })) };
};
window.zcut.unsaved = () => [...loaded.values()].filter((fd) => fd.dirty || fd.saving || fd.conflict).map((fd) => fd.index);
window.zcut.profileInfo = () => $('profinfo').textContent;

canvas.addEventListener('contextmenu', (e) => e.preventDefault());
canvas.addEventListener('pointerdown', (e) => {
  const fd = state.cur; if (!fd) return;
  canvas.setPointerCapture(e.pointerId);
  window.zcut.inputs++;
  const p = toImage(e);
  if (e.button === 2 || e.button === 1 || spaceDown) {
    window.zcut.pans++;
    drag = { kind: 'pan', sx: e.clientX, sy: e.clientY, px: state.px, py: state.py };
    return;
  }
  if (e.button !== 0) return;
  if (e.ctrlKey || e.metaKey) { seedFit(fd, p.x, p.y); return; }  // Ctrl+click: seed a missed instance
  const t = state.tool;
  if (t === 'select') { clickCluster(fd, p.x, p.y, e.altKey); return; }
  if (t === 'wand') { wand(fd, p.x, p.y, e.shiftKey ? 'erase' : 'add'); return; }
  if (t === 'brush' || t === 'eraser' || t === 'unreviewed' || t === 'rbrush') {
    const mode = t === 'brush' ? 'add' : t === 'eraser' ? 'erase' : t === 'rbrush' ? (e.shiftKey ? 'rerase' : 'radd') : 'unreview';
    beginAction(fd);
    if (t === 'rbrush') {
      const x = Math.floor(p.x), y = Math.floor(p.y);
      rbrushGroup = x >= 0 && y >= 0 && x < fd.W && y < fd.H ? fd.gIds[y * fd.W + x] : 0;
    }
    paintDisc(fd, p.x, p.y, state.brush, mode);
    drag = { kind: 'paint', mode, last: p };
    requestDraw();
  } else if (t === 'box') {
    drag = { kind: 'box', x0: p.x, y0: p.y, x: p.x, y: p.y, erase: e.shiftKey };
  } else if (t === 'lasso') {
    drag = { kind: 'lasso', pts: [[p.x, p.y]], erase: e.shiftKey };
  } else if (t === 'profile') {
    drag = { kind: 'profile', x0: p.x, y0: p.y, x: p.x, y: p.y };
  }
});
canvas.addEventListener('pointermove', (e) => {
  const p = toImage(e);
  hover = p;
  const fd = state.cur;
  if (drag && fd) {
    if (drag.kind === 'pan') { state.px = drag.px + e.clientX - drag.sx; state.py = drag.py + e.clientY - drag.sy; }
    else if (drag.kind === 'paint') { paintLine(fd, drag.last, p, drag.mode); drag.last = p; }
    else if (drag.kind === 'box' || drag.kind === 'profile') { drag.x = p.x; drag.y = p.y; }
    else if (drag.kind === 'lasso') drag.pts.push([p.x, p.y]);
  }
  updateReadout();
  requestDraw();
});
canvas.addEventListener('pointerup', (e) => {
  const fd = state.cur, d = drag; drag = null;
  if (!d || !fd) return;
  if (d.kind === 'paint') {
    if ((d.mode === 'radd' || d.mode === 'rerase') && rbrushGroup > 0) {
      const g = fd.base.find((b) => b.src === 'g' && b.id === rbrushGroup);
      if (g) {  // the group's pixels the brush left: reviewed, not outliers (the group is decided)
        for (const i of g.pix) if (fd.valid[i] && !fd.R[i]) { fd.R[i] = 1; fd.L[i] = 0; }
        touch(g.x0, g.y0, g.x1, g.y1); renderOverlay(g.x0, g.y0, g.x1, g.y1);
      }
    }
    rbrushGroup = -1;
    endAction(fd);
  } else if (d.kind === 'box') {
    const pts = [[d.x0, d.y0], [d.x, d.y0], [d.x, d.y], [d.x0, d.y]];
    beginAction(fd); fillPolygon(fd, pts, d.erase || e.shiftKey ? 'erase' : 'add'); endAction(fd);
  } else if (d.kind === 'lasso' && d.pts.length > 2) {  // only the suspects (review groups' pixels) inside
    beginAction(fd); fillPolygon(fd, d.pts, d.erase || e.shiftKey ? 'erase' : 'add', (i) => fd.gIds[i] !== 0); endAction(fd);
  } else if (d.kind === 'profile') {
    const c = (v, hi) => Math.max(0, Math.min(hi - 1, Math.floor(v)));
    state.profile = { x0: c(d.x0, fd.W), y0: c(d.y0, fd.H), x1: c(d.x, fd.W), y1: c(d.y, fd.H),
                      entry: state.sel >= 0 ? fd.entries[state.sel] : null };
    const pr = state.profile;
    ensureTiles(fd, Math.min(pr.x0, pr.x1), Math.min(pr.y0, pr.y1), Math.max(pr.x0, pr.x1) + 1, Math.max(pr.y0, pr.y1) + 1)
      .then(() => drawProfile(), (err) => showError(String(err)));
  }
  requestDraw();
});
canvas.addEventListener('pointerleave', () => { hover = null; updateReadout(); requestDraw(); });
canvas.addEventListener('wheel', (e) => {
  e.preventDefault();
  const r = canvas.getBoundingClientRect();
  const mx = e.clientX - r.left, my = e.clientY - r.top;
  const f = Math.exp(-e.deltaY * 0.0015), z = Math.min(64, Math.max(0.05, state.zoom * f));
  state.px = mx - (mx - state.px) * z / state.zoom; state.py = my - (my - state.py) * z / state.zoom;
  state.zoom = z;
  requestDraw();
}, { passive: false });
function minimapGo(e) {
  const fd = state.cur; if (!fd) return;
  const r = $('minimap').getBoundingClientRect();
  const x = (e.clientX - r.left) / r.width * fd.W, y = (e.clientY - r.top) / r.height * fd.H;
  state.px = canvas.clientWidth / 2 - x * state.zoom; state.py = canvas.clientHeight / 2 - y * state.zoom;
  requestDraw();
}
$('minimap').addEventListener('pointerdown', (e) => { window.zcut.inputs++; $('minimap').setPointerCapture(e.pointerId); minimapGo(e); });
$('minimap').addEventListener('pointermove', (e) => { if (e.buttons) minimapGo(e); });

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
function setRise(v) {  // the wand's and the residual brush's threshold (mm)
  state.riseMm = Math.max(0.1, Math.min(25, Math.round(10 * v) / 10));
  $('rise').value = state.riseMm; $('riseval').textContent = state.riseMm.toFixed(1);
  requestDraw();
}
function setSorMin(v) {
  state.sorMin = Math.max(1, Math.min(200, v | 0));
  $('sormin').value = state.sorMin; $('sorminval').textContent = state.sorMin;
  const fd = state.cur;
  if (fd) { refreshList(fd, true); renderOverlay(); requestDraw(); }
}
function setOverlay(on) {  // O: the whole overlay (masks, outlines, markers, Err labels) shown or hidden; nothing else changes
  state.showOv = on; $('showOv').checked = on;
  requestDraw();
}
function toggle(key) {
  state[key] = !state[key]; $(key).checked = state[key];
  if (state.cur) { refreshList(state.cur, true); renderOverlay(); }
  requestDraw();
}

window.addEventListener('keydown', (e) => {
  if (e.target instanceof HTMLInputElement && e.target.type === 'text') return;
  const k = e.key, fd = state.cur;
  const ctrl = e.ctrlKey || e.metaKey;
  const t0 = e.timeStamp || performance.now();
  if (k === ' ') { spaceDown = true; e.preventDefault(); return; }
  if (ctrl && (k === 'z' || k === 'Z')) { e.shiftKey ? redo() : undo(); e.preventDefault(); window.zcut.inputs++; return; }
  if (ctrl && (k === 'y' || k === 'Y')) { redo(); e.preventDefault(); window.zcut.inputs++; return; }
  if (ctrl || e.altKey) return;
  switch (k) {
    case 'Tab': if (fd && fd.entries.length) {
      const n = fd.entries.length, d = e.shiftKey ? -1 : 1;
      select(state.sel < 0 ? (d > 0 ? 0 : n - 1) : (state.sel + d + n) % n, { zoom: true, t0 });
    } break;
    case 'a': decide(true, t0); break;
    case 'r': decide(false, t0); break;
    case 'A': decideAll(true); break;
    case 'y': case 'Y': acceptProposals(); break;
    case 'k': case 'K': rejectFit(); break;
    case 'w': case 'W': setTool('wand'); break;
    case 't': case 'T': setTool('rbrush'); break;
    case ',': setRise(riseThreshold(fd || { header: {} }) - 0.1); break;
    case '.': setRise(riseThreshold(fd || { header: {} }) + 0.1); break;
    case 'g': case 'G': toggle('showG'); break;
    case 'R': decideAll(false); break;
    case 'Escape': if (fd) select(-1); break;
    case 'c': case 'C': if (fd && state.sel >= 0) zoomTo(fd.entries[state.sel]); break;
    case 'ArrowRight': case 'PageDown': step(1, t0); break;
    case 'ArrowLeft': case 'PageUp': step(-1, t0); break;
    case 'n': case 'N': nextUnreviewed(); break;
    case 'Enter': markReviewedAndNext(t0); break;
    case 'v': case 'V': setTool('select'); break;
    case 'b': case 'B': setTool('brush'); break;
    case 'e': case 'E': setTool('eraser'); break;
    case 'x': case 'X': setTool('box'); break;
    case 'l': case 'L': setTool('lasso'); break;
    case 'u': setTool('unreviewed'); break;
    case 'U': decideAll(true, true); break;  // Shift+U: every undecided proposal of the fits, as outliers
    case 'p': case 'P': setTool('profile'); break;
    case '[': setBrush(state.brush - (state.brush > 10 ? 2 : 1)); break;
    case ']': setBrush(state.brush + (state.brush >= 10 ? 2 : 1)); break;
    case 'z': undo(); break;
    case 'Z': redo(); break;
    case 'f': case 'F': case '0': fit(); break;
    case 'm': case 'M': state.showMini = !state.showMini; requestDraw(); break;
    case 'd': case 'D': if (fd && fd.conflict) setConflictView({ mine: 'theirs', theirs: 'diff', diff: 'mine' }[state.conflictView]); break;
    case '1': toggle('showZ'); break;
    case '2': toggle('showS'); break;
    case '3': toggle('showL'); break;
    case 'h': case 'H': toggle('showH'); break;
    case '4': toggle('showF'); break;
    case 'o': case 'O': setOverlay(!state.showOv); break;
    case 'j': jumpUndecided(1); break;
    case 'J': jumpUndecided(-1); break;
    default: return;
  }
  window.zcut.inputs++;
  e.preventDefault();
});
window.addEventListener('keyup', (e) => { if (e.key === ' ') spaceDown = false; });
window.addEventListener('resize', () => requestDraw());
window.addEventListener('pagehide', flushOnLeave);
document.addEventListener('visibilitychange', () => { if (document.visibilityState === 'hidden') flushOnLeave(); });
window.addEventListener('beforeunload', (e) => {  // only if the keepalive request could not carry the edit
  const fd = state.cur;
  if (fd && fd.dirty && labelBody(fd, 0).length > KEEPALIVE_MAX) { e.preventDefault(); e.returnValue = ''; }
});

const buttonAction = (f) => () => { window.zcut.inputs++; f(); document.activeElement.blur(); };
for (const b of document.querySelectorAll('#tools button')) b.onclick = buttonAction(() => setTool(b.dataset.tool));
$('brushsize').oninput = (e) => setBrush(+e.target.value);
$('rise').oninput = (e) => setRise(+e.target.value);
$('sormin').oninput = (e) => setSorMin(+e.target.value);
for (const key of ['showG', 'showZ', 'showS', 'showL', 'showH', 'showF']) $(key).onchange = () => { toggle(key); $(key).blur(); };
$('showOv').onchange = () => { setOverlay($('showOv').checked); $('showOv').blur(); };
$('sortkey').onchange = (e) => { state.sortKey = e.target.value; e.target.blur(); if (state.cur) refreshList(state.cur, true); requestDraw(); };
$('orderby').onchange = (e) => { setOrder(e.target.value); e.target.blur(); };
$('prev').onclick = buttonAction(() => step(-1));
$('next').onclick = buttonAction(() => step(1));
$('done').onclick = buttonAction(() => markReviewedAndNext());
$('undo').onclick = buttonAction(undo); $('redo').onclick = buttonAction(redo);
$('accept').onclick = buttonAction(() => decide(true)); $('reject').onclick = buttonAction(() => decide(false));
$('lostform').onsubmit = (ev) => { ev.preventDefault(); reconnect($('lostin').value).catch((e) => showError(String(e))); };
for (const b of document.querySelectorAll('#conflict [data-merge]')) b.onclick = buttonAction(() => resolveConflict(b.dataset.merge));
for (const b of document.querySelectorAll('#conflict [data-view]')) b.onclick = buttonAction(() => setConflictView(b.dataset.view));

// ------------------------------------------------------------------ the annotator (chosen once)
function chooseAnnotator() {
  return new Promise((resolve) => {
    const box = $('namebox'), input = $('namein'), msg = $('namemsg');
    box.hidden = false; input.focus();
    $('nameform').onsubmit = async (ev) => {
      ev.preventDefault();
      const r = await fetch('/api/annotator', { method: 'POST', headers: { 'Content-Type': 'application/json' },
                                                body: JSON.stringify({ name: input.value }) });
      const j = await r.json().catch(() => ({}));
      if (r.ok || r.status === 409 && j.annotator) { box.hidden = true; resolve(j.annotator); }
      else msg.textContent = j.error || `HTTP ${r.status}`;
    };
  });
}

// ------------------------------------------------------------------ start
(async () => {
  $('logname').textContent = BOOT.log;
  setTool('select'); setBrush(8); setSorMin(state.sorMin);
  const s = await refreshSession();
  state.turbo = s.turbo; state.sha256 = s.sha256;
  if (!state.annotator) state.annotator = await chooseAnnotator();
  $('who').textContent = `annotator: ${state.annotator}`;
  $('who').title = state.mode === 'fixed' ? 'set when the server started (zcut annotate --annotator)'
    : 'chosen for this page session; it does not change';
  showFocus(s.focus);
  const notes = s.notes.concat((s.damage || []).map((d) => `data loss: ${d}`));
  if (notes.length) $('notes').textContent = notes.join('\n');
  await refreshFrames();
  while (!state.frames.length && !state.done) { await new Promise((r) => setTimeout(r, 300)); await refreshFrames(); }
  if (!state.done) refreshFrames({ again: true });
  const want = parseInt(location.hash.slice(1), 10);
  await goTo(Number.isFinite(want) && frameRow(want) ? want : state.order[0]);
  flushPending();
  pollAssistant();
  window.zcut.ready = true;
})().catch((e) => showError(String(e)));
