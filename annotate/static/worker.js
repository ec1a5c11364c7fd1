// zcut labelling page: loading and decoding off the main thread, so that a frame switch only draws.
// Messages in:  {id, type: 'frame', index, flags, imageId}
//               (two replies: the masks, candidates and overlay pixels under id, then the overlay
//               as an ImageBitmap {overlay} under imageId; the page decodes the JPEG in a second worker)
//               {id, type: 'image', index, kind: 'rgb'|'height'} -> {bitmap}
//               {id, type: 'label', index, W, H} -> the annotator's latest label
// Messages out: {id, ok: true, ...result} or {id, ok: false, error}
// Requests carry the page's session cookie (same origin); a frame still being prepared answers 503
// with Retry-After and is asked again (the reply says how long it waited).
'use strict';

async function fetchOk(path) {
  for (let tries = 0; ; tries++) {
    const r = await fetch(path);
    if (r.status === 503 && tries < 600) {
      const wait = Math.min(5, Math.max(0.2, parseFloat(r.headers.get('Retry-After') || '1')));
      await new Promise((res) => setTimeout(res, wait * 1000));
      continue;
    }
    if (!r.ok) throw new Error(`${path}: HTTP ${r.status} ${(await r.text()).slice(0, 200)}`);
    return r;
  }
}
async function inflate(u8) {
  const s = new Blob([u8]).stream().pipeThrough(new DecompressionStream('deflate'));
  return new Uint8Array(await new Response(s).arrayBuffer());
}
function unpackBits(bytes, n) {
  const out = new Uint8Array(n);
  const full = n >> 3;
  for (let b = 0; b < full; b++) {
    const v = bytes[b];
    if (v === 0) continue;
    const o = b << 3;
    if (v === 255) { out[o] = out[o + 1] = out[o + 2] = out[o + 3] = out[o + 4] = out[o + 5] = out[o + 6] = out[o + 7] = 1; continue; }
    out[o] = v >> 7; out[o + 1] = (v >> 6) & 1; out[o + 2] = (v >> 5) & 1; out[o + 3] = (v >> 4) & 1;
    out[o + 4] = (v >> 3) & 1; out[o + 5] = (v >> 2) & 1; out[o + 6] = (v >> 1) & 1; out[o + 7] = v & 1;
  }
  for (let i = full << 3; i < n; i++) out[i] = (bytes[i >> 3] >> (7 - (i & 7))) & 1;
  return out;
}
function anyByte(u8) { for (let i = 0; i < u8.length; i++) if (u8[i]) return true; return false; }
function unpackRuns(raw, n) {  // uint32 run lengths: false, true, false, ...
  const out = new Uint8Array(n), runs = new Uint32Array(raw.buffer, raw.byteOffset, raw.byteLength >> 2);
  let p = 0;
  for (let k = 0; k < runs.length; k++) { const e = p + runs[k]; if (k & 1) out.fill(1, p, e); p = e; }
  if (p !== n) throw new Error(`runs cover ${p} pixels, not ${n}`);
  return out;
}
// A bundle (see annotate/payload.py) from the bytes u8 (a view into a larger buffer is fine).
// arrays[name + 'Any'] tells whether a mask has any pixel set, from its compressed form.
async function parseBundle(u8) {
  const dv = new DataView(u8.buffer, u8.byteOffset, u8.byteLength);
  const n = dv.getUint32(0, true);
  const header = JSON.parse(new TextDecoder().decode(u8.subarray(4, 4 + n)));
  const base = 4 + n, npx = header.height * header.width, out = {};
  await Promise.all(header.sections.map(async (s) => {
    const bytes = u8.subarray(base + s.offset, base + s.offset + s.length);
    const raw = s.zlib === false ? bytes.slice() : await inflate(bytes);  // slice: aligned, owned
    if (s.kind === 'bits') { out[s.name + 'Any'] = anyByte(raw); out[s.name] = unpackBits(raw, npx); }
    else if (s.kind === 'runs') { out[s.name] = unpackRuns(raw, npx); out[s.name + 'Any'] = raw.byteLength > 4; }
    else if (s.kind === 'sparse') {
      const n = s.count;
      const Arr = s.dtype === 'uint8' ? Uint8Array : s.dtype === 'uint16' ? Uint16Array : Uint32Array;
      const deltas = new Uint32Array(raw.buffer, raw.byteOffset, n);
      const values = new Arr(raw.buffer.slice(raw.byteOffset + 4 * n, raw.byteOffset + 4 * n + n * Arr.BYTES_PER_ELEMENT));
      const dense = new Arr(npx), idx = new Uint32Array(n);
      let p = 0;
      for (let k = 0; k < n; k++) { p += deltas[k]; idx[k] = p; dense[p] = values[k]; }
      out[s.name] = dense; out[s.name + 'Idx'] = idx; out[s.name + 'Val'] = values;
    }
    else if (s.kind === 'table') out[s.name] = new Float32Array(raw.buffer, raw.byteOffset, s.rows * s.cols);
    else if (s.dtype === 'uint8') out[s.name] = raw;
    else if (s.dtype === 'uint16') out[s.name] = new Uint16Array(raw.buffer, raw.byteOffset, npx);
    else out[s.name] = new Uint32Array(raw.buffer, raw.byteOffset, npx);
  }));
  return { header, arrays: out };
}
// A view (annotate/payload.py make_view): name -> Uint8Array into buf.
function parseView(buf) {
  const n = new DataView(buf).getUint32(0, true);
  const head = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, 4, n)));
  const parts = {};
  for (const [name, off, len] of head.parts) parts[name] = new Uint8Array(buf, 4 + n + off, len);
  return parts;
}
// The pixels of each cluster id, grouped: pixels of id k are pix[start[k] .. start[k + 1]).
function groupById(idx, values, nIds) {
  const start = new Uint32Array(nIds + 2);
  for (let k = 0; k < values.length; k++) start[values[k] + 1]++;
  for (let k = 1; k < start.length; k++) start[k] += start[k - 1];
  const fill = start.slice(0, nIds + 1), pix = new Uint32Array(idx.length);
  for (let k = 0; k < values.length; k++) pix[fill[values[k]]++] = idx[k];
  return { start, pix };
}

// Overlay colours (RGBA little endian in a Uint32Array), as app.js paints them.
function rgba(r, g, b, a) { return ((a << 24) | (b << 16) | (g << 8) | r) >>> 0; }
const COL_L = rgba(255, 30, 60, 200), COL_Z = rgba(255, 170, 0, 150), COL_S = rgba(40, 150, 255, 140);
const COL_ZS = rgba(190, 90, 255, 160), COL_UNREV = rgba(0, 0, 0, 150);
const COL_G = rgba(0, 230, 230, 150), COL_GR = rgba(0, 120, 90, 110);  // review groups: undecided, reviewed
// The overlay from the candidates' pixel lists: the dense loop only where R is shaded.
function renderOverlaySparse(ov32, f, lab, valid, sIds, zIdx, sIdx, sSize, gIdx) {
  // ov32 is a fresh (all 0) buffer
  const { L, R } = lab;
  if (lab.shade) for (let i = 0; i < ov32.length; i++) if (valid[i] && !R[i]) ov32[i] = COL_UNREV;
  if (f.showS) for (let k = 0; k < sIdx.length; k++) { const i = sIdx[k]; if (sSize[sIds[i]] >= f.sorMin) ov32[i] = COL_S; }
  if (f.showZ) for (let k = 0; k < zIdx.length; k++) {
    const i = zIdx[k];
    ov32[i] = (f.showS && sIds[i] !== 0 && sSize[sIds[i]] >= f.sorMin) ? COL_ZS : COL_Z;
  }
  // a review group's pixels show as the group over the z-cut and SOR colours (as renderOverlay draws them)
  if (f.showG) for (let k = 0; k < gIdx.length; k++) { const i = gIdx[k]; ov32[i] = R[i] ? COL_GR : COL_G; }
  if (f.showL && lab.hasL) for (let i = 0; i < L.length; i++) if (L[i]) ov32[i] = COL_L;
}

function count(u8) { let n = 0; for (let i = 0; i < u8.length; i++) n += u8[i]; return n; }
function labelFrom({ header, arrays }, npx, nValid) {
  const L = arrays.outliers || new Uint8Array(npx), R = arrays.reviewed || new Uint8Array(npx);
  const nR = arrays.reviewedAny ? count(R) : 0;
  return { rev: header.revision, L, R, nR, hasL: !!arrays.outliersAny, shade: 2 * nR >= nValid && nR > 0 };
}

async function handle(m) {
  if (m.type === 'frame') {
    const t0 = performance.now();
    const r = await fetchOk(`/api/frames/${m.index}/view?image=none`);
    const parts = parseView(await r.arrayBuffer());
    const t1 = performance.now();
    const [{ header, arrays }, labelBundle] = await Promise.all([parseBundle(parts.bundle), parseBundle(parts.label)]);
    const t2 = performance.now();
    const npx = header.width * header.height;
    const lab = labelFrom(labelBundle, npx, header.n_valid);
    const z = groupById(arrays.zcutIdx, arrays.zcutVal, header.n_zcut);
    const s = groupById(arrays.sorIdx, arrays.sorVal, header.n_sor);
    const g = groupById(arrays.groupsIdx, arrays.groupsVal, header.n_groups || 0);
    const sSize = new Uint32Array(header.n_sor + 1);
    for (let k = 1; k <= header.n_sor; k++) sSize[k] = s.start[k + 1] - s.start[k];
    const t3 = performance.now();
    const ov = new Uint8ClampedArray(npx * 4);
    renderOverlaySparse(new Uint32Array(ov.buffer), m.flags, lab, arrays.valid, arrays.sor, arrays.zcutIdx,
                        arrays.sorIdx, sSize, arrays.groupsIdx);
    const t4 = performance.now();
    // the masks go out at once (the page uploads the overlay while the JPEG still decodes); the
    // overlay bitmap follows as its own reply, under m.imageId
    const overlay = createImageBitmap(new ImageData(ov, header.width, header.height));  // copies ov
    overlay.then(
      (o) => self.postMessage({ id: m.imageId, ok: true, overlay: o }, [o]),
      (err) => self.postMessage({ id: m.imageId, ok: false, error: String(err) }));
    const timing = { fetch: t1 - t0, parse: t2 - t1, label: t3 - t2, overlay: t4 - t3 };
    const res = {
      timing, header, valid: arrays.valid, zone: arrays.zone || null, zIds: arrays.zcut, sIds: arrays.sor,
      cand: arrays.candidates, zStart: z.start, zPix: z.pix, sStart: s.start, sPix: s.pix, sSize, ...lab, ov,
      gIds: arrays.groups, gStart: g.start, gPix: g.pix, gTable: arrays.group_table, rise: arrays.rise,
    };
    const transfer = [arrays.valid.buffer, arrays.zcut.buffer, arrays.sor.buffer, arrays.candidates.buffer, z.start.buffer,
                      z.pix.buffer, s.start.buffer, s.pix.buffer, sSize.buffer, lab.L.buffer, lab.R.buffer, ov.buffer];
    if (arrays.zone) transfer.push(arrays.zone.buffer);
    transfer.push(arrays.groups.buffer, g.start.buffer, g.pix.buffer, arrays.group_table.buffer, arrays.rise.buffer);
    return [res, [...new Set(transfer)]];
  }
  if (m.type === 'image') {  // the picture, and a small copy for the minimap
    const t0 = performance.now();
    const blob = await (await fetchOk(`/api/frames/${m.index}/image/${m.kind}`)).blob();
    const bmp = await createImageBitmap(blob);
    const w = 440, h = Math.max(1, Math.round(440 * bmp.height / bmp.width));
    const small = await createImageBitmap(bmp, { resizeWidth: w, resizeHeight: h, resizeQuality: 'medium' });
    return [{ bitmap: bmp, small, decoded: performance.now() - t0 }, [bmp, small]];
  }
  if (m.type === 'label') {
    const r = await fetchOk(`/api/frames/${m.index}/label`);
    const lab = labelFrom(await parseBundle(new Uint8Array(await r.arrayBuffer())), m.W * m.H, m.nValid);
    return [lab, [lab.L.buffer, lab.R.buffer]];
  }
  throw new Error(`unknown message ${m.type}`);
}

self.onmessage = async (e) => {
  const m = e.data;
  try {
    const [res, transfer] = await handle(m);
    self.postMessage({ id: m.id, ok: true, ...res }, transfer);
  } catch (err) {
    self.postMessage({ id: m.id, ok: false, error: String(err) });
  }
};
