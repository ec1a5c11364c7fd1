// zcut labelling page: loading and packing off the main thread, so that a frame switch only draws.
// Messages in:  {id, type: 'frame', index, annotator, flags, imageId}
//               (two replies: the masks and overlay pixels under id, then the overlay as an
//               ImageBitmap {overlay} under imageId; the page decodes the JPEG in a second worker)
//               {id, type: 'image', index, kind: 'rgb'|'height'} -> {bitmap}
//               {id, type: 'label', index, annotator, W, H}
//               {id, type: 'pack', L, R}
// Messages out: {id, ok: true, ...result} or {id, ok: false, error}
'use strict';

let TOKEN = null;

function api(path) { return fetch(path, { headers: { 'X-Zcut-Token': TOKEN } }); }
async function fetchOk(path) {
  const r = await api(path);
  if (!r.ok) throw new Error(`${path}: HTTP ${r.status}`);
  return r;
}
async function inflate(u8) {
  const s = new Blob([u8]).stream().pipeThrough(new DecompressionStream('deflate'));
  return new Uint8Array(await new Response(s).arrayBuffer());
}
async function deflate(u8) {
  const s = new Blob([u8]).stream().pipeThrough(new CompressionStream('deflate'));
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
function packBits(a) {
  const n = a.length, out = new Uint8Array((n + 7) >> 3);
  for (let i = 0; i < n; i++) if (a[i]) out[i >> 3] |= 128 >> (i & 7);
  return out;
}
function b64(u8) {
  let s = '';
  for (let i = 0; i < u8.length; i += 0x8000) s += String.fromCharCode.apply(null, u8.subarray(i, i + 0x8000));
  return btoa(s);
}
function anyByte(u8) { for (let i = 0; i < u8.length; i++) if (u8[i]) return true; return false; }
function unpackRuns(raw, n) {  // uint32 run lengths: false, true, false, ...
  const out = new Uint8Array(n), runs = new Uint32Array(raw.buffer, raw.byteOffset, raw.byteLength >> 2);
  let p = 0;
  for (let k = 0; k < runs.length; k++) { const e = p + runs[k]; if (k & 1) out.fill(1, p, e); p = e; }
  if (p !== n) throw new Error(`runs cover ${p} pixels, not ${n}`);
  return out;
}
// A bundle (see annotate/frames.py) from the bytes u8 (a view into a larger buffer is fine).
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
      out[s.name] = dense; out[s.name + 'Idx'] = idx;
    }
    else if (s.dtype === 'uint8') out[s.name] = raw;
    else if (s.dtype === 'uint16') out[s.name] = new Uint16Array(raw.buffer, raw.byteOffset, npx);
    else out[s.name] = new Uint32Array(raw.buffer, raw.byteOffset, npx);
  }));
  return { header, arrays: out };
}
// A view (annotate/frames.py make_view): name -> Uint8Array into buf.
function parseView(buf) {
  const n = new DataView(buf).getUint32(0, true);
  const head = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, 4, n)));
  const parts = {};
  for (const [name, off, len] of head.parts) parts[name] = new Uint8Array(buf, 4 + n + off, len);
  return parts;
}

// Overlay colours (RGBA little endian in a Uint32Array), as app.js paints them.
function rgba(r, g, b, a) { return ((a << 24) | (b << 16) | (g << 8) | r) >>> 0; }
const COL_L = rgba(255, 30, 60, 200), COL_Z = rgba(255, 170, 0, 120), COL_S = rgba(40, 150, 255, 120);
const COL_ZS = rgba(190, 90, 255, 140), COL_UNREV = rgba(0, 0, 0, 150);
// The same picture from the candidates' pixel lists: the dense loop only where R is partial.
function renderOverlaySparse(ov32, f, L, R, valid, sIds, zIdx, sIdx, hasR, hasL) {
  // ov32 is a fresh (all 0) buffer
  if (hasR) for (let i = 0; i < ov32.length; i++) if (valid[i] && !R[i]) ov32[i] = COL_UNREV;
  if (f.showS) for (let k = 0; k < sIdx.length; k++) ov32[sIdx[k]] = COL_S;
  if (f.showZ) for (let k = 0; k < zIdx.length; k++) { const i = zIdx[k]; ov32[i] = (f.showS && sIds[i] !== 0) ? COL_ZS : COL_Z; }
  if (f.showL && hasL) for (let i = 0; i < L.length; i++) if (L[i]) ov32[i] = COL_L;
}

function labelFrom({ header, arrays }, npx) {
  const L = arrays.outliers || new Uint8Array(npx), R = arrays.reviewed || new Uint8Array(npx);
  return { rev: header.revision, L, R, hasR: header.revision > 0 && !!arrays.reviewedAny,
           hasL: !!arrays.outliersAny };
}
async function loadLabel(index, annotator, npx) {
  const r = await fetchOk(`/api/frames/${index}/label?annotator=${encodeURIComponent(annotator)}`);
  return labelFrom(await parseBundle(new Uint8Array(await r.arrayBuffer())), npx);
}

async function handle(m) {
  if (m.type === 'frame') {
    // one request (bundle + label + JPEG); the JPEG decodes while the masks unpack
    const t0 = performance.now();
    const r = await fetchOk(`/api/frames/${m.index}/view?annotator=${encodeURIComponent(m.annotator)}&image=none`);
    const parts = parseView(await r.arrayBuffer());
    const t1 = performance.now();
    const [{ header, arrays }, labelBundle] = await Promise.all([parseBundle(parts.bundle), parseBundle(parts.label)]);
    const t2 = performance.now();
    const npx = header.width * header.height;
    const lab = labelFrom(labelBundle, npx);
    const t3 = performance.now();
    const ov = new Uint8ClampedArray(npx * 4);
    renderOverlaySparse(new Uint32Array(ov.buffer), m.flags, lab.L, lab.R, arrays.valid, arrays.sor,
                        arrays.zcutIdx, arrays.sorIdx, lab.hasR, lab.hasL);
    const t4 = performance.now();
    // the masks go out at once (the page uploads the overlay while the JPEG still decodes); the
    // image follows as its own reply, under m.imageId
    const overlay = createImageBitmap(new ImageData(ov, header.width, header.height));  // copies ov
    overlay.then(
      (o) => self.postMessage({ id: m.imageId, ok: true, overlay: o }, [o]),
      (err) => self.postMessage({ id: m.imageId, ok: false, error: String(err) }));
    const timing = { fetch: t1 - t0, parse: t2 - t1, label: t3 - t2, overlay: t4 - t3 };
    const res = { timing, header, valid: arrays.valid, zIds: arrays.zcut, sIds: arrays.sor, ...lab, ov };
    const transfer = [arrays.valid.buffer, arrays.zcut.buffer, arrays.sor.buffer, lab.L.buffer, lab.R.buffer, ov.buffer];
    return [res, [...new Set(transfer)]];
  }
  if (m.type === 'image') {
    const t0 = performance.now();
    const bmp = await createImageBitmap(await (await fetchOk(`/api/frames/${m.index}/image/${m.kind}`)).blob());
    return [{ bitmap: bmp, decoded: performance.now() - t0 }, [bmp]];
  }
  if (m.type === 'label') {
    const lab = await loadLabel(m.index, m.annotator, m.W * m.H);
    return [lab, [lab.L.buffer, lab.R.buffer]];
  }
  if (m.type === 'pack') {
    const [l, r] = await Promise.all([deflate(packBits(m.L)), deflate(packBits(m.R))]);
    return [{ outliers: b64(l), reviewed: b64(r) }, []];
  }
  throw new Error(`unknown message ${m.type}`);
}

self.onmessage = async (e) => {
  const m = e.data;
  if (m.type === 'token') { TOKEN = m.token; return; }
  try {
    const [res, transfer] = await handle(m);
    self.postMessage({ id: m.id, ok: true, ...res }, transfer);
  } catch (err) {
    self.postMessage({ id: m.id, ok: false, error: String(err) });
  }
};
