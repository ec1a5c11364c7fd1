// zcut labelling page: a small 3D view of a cluster's neighbourhood — WebGL points with an orbit
// camera (drag: turn, wheel: distance), a plain 2D canvas when WebGL is not available.
// Points are given in millimetres with z up; colours as RGB bytes; `big` marks the points drawn larger
// (the selected cluster).
'use strict';

function perspective(fovy, aspect, near, far) {
  const f = 1 / Math.tan(fovy / 2), nf = 1 / (near - far);
  return [f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) * nf, -1, 0, 0, 2 * far * near * nf, 0];
}
function mul(a, b) {  // column-major 4x4: a * b
  const o = new Array(16).fill(0);
  for (let c = 0; c < 4; c++) for (let r = 0; r < 4; r++) {
    let s = 0;
    for (let k = 0; k < 4; k++) s += a[k * 4 + r] * b[c * 4 + k];
    o[c * 4 + r] = s;
  }
  return o;
}
function rotX(t) { const c = Math.cos(t), s = Math.sin(t); return [1, 0, 0, 0, 0, c, s, 0, 0, -s, c, 0, 0, 0, 0, 1]; }
function rotZ(t) { const c = Math.cos(t), s = Math.sin(t); return [c, s, 0, 0, -s, c, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]; }
function translate(x, y, z) { return [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, x, y, z, 1]; }

const VS = `attribute vec3 pos; attribute vec3 col; uniform mat4 mvp; uniform float size; varying vec3 v;
void main() { gl_Position = mvp * vec4(pos, 1.0); gl_PointSize = size; v = col; }`;
const FS = `precision mediump float; varying vec3 v; void main() { gl_FragColor = vec4(v, 1.0); }`;

export class PointView {
  constructor(canvas) {
    this.canvas = canvas;
    this.yaw = -0.5; this.pitch = -1.05; this.dist = 100; this.radius = 40;
    this.n = 0; this.nBig = 0;
    this.gl = canvas.getContext('webgl', { antialias: false, preserveDrawingBuffer: true });
    this.kind = this.gl ? 'webgl' : '2d';
    if (this.gl) this._initGl(); else this.ctx = canvas.getContext('2d');
    let drag = null;
    canvas.addEventListener('pointerdown', (e) => { drag = { x: e.clientX, y: e.clientY, yaw: this.yaw, pitch: this.pitch }; canvas.setPointerCapture(e.pointerId); });
    canvas.addEventListener('pointermove', (e) => {
      if (!drag) return;
      this.yaw = drag.yaw + (e.clientX - drag.x) * 0.01;
      this.pitch = Math.max(-Math.PI, Math.min(0, drag.pitch + (e.clientY - drag.y) * 0.01));
      this.draw();
    });
    canvas.addEventListener('pointerup', () => { drag = null; });
    canvas.addEventListener('wheel', (e) => {
      e.preventDefault();
      this.dist = Math.max(this.radius * 0.3, Math.min(this.radius * 12, this.dist * Math.exp(e.deltaY * 0.0015)));
      this.draw();
    }, { passive: false });
  }

  _initGl() {
    const gl = this.gl;
    const sh = (type, src) => {
      const s = gl.createShader(type); gl.shaderSource(s, src); gl.compileShader(s);
      if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
      return s;
    };
    const p = gl.createProgram();
    gl.attachShader(p, sh(gl.VERTEX_SHADER, VS)); gl.attachShader(p, sh(gl.FRAGMENT_SHADER, FS));
    gl.linkProgram(p);
    this.prog = p;
    this.aPos = gl.getAttribLocation(p, 'pos'); this.aCol = gl.getAttribLocation(p, 'col');
    this.uMvp = gl.getUniformLocation(p, 'mvp'); this.uSize = gl.getUniformLocation(p, 'size');
    this.bPos = gl.createBuffer(); this.bCol = gl.createBuffer();
  }

  // pos: Float32Array (n*3) mm, z up, around the origin; col: Uint8Array (n*3); the first nBig
  // points are drawn larger; radius: the neighbourhood's half size (mm) for the camera distance.
  setPoints(pos, col, nBig, radius) {
    this.pos = pos; this.col = col; this.n = pos.length / 3; this.nBig = nBig;
    // the whole bounding sphere in view (a cluster 60-85 mm above the surface sits at its top: a camera
    // fitted to 80 % of it lost such clusters); every new neighbourhood starts from that distance
    this.radius = radius; this.dist = 1.15 * radius / Math.sin(0.3);
    if (this.gl) {
      const gl = this.gl;
      gl.bindBuffer(gl.ARRAY_BUFFER, this.bPos); gl.bufferData(gl.ARRAY_BUFFER, pos, gl.STATIC_DRAW);
      gl.bindBuffer(gl.ARRAY_BUFFER, this.bCol); gl.bufferData(gl.ARRAY_BUFFER, col, gl.STATIC_DRAW);
    }
    this.draw();
  }

  clear() {  // nothing shown (another frame)
    this.n = 0;
    if (this.gl) { const gl = this.gl; gl.clearColor(0.07, 0.07, 0.08, 1); gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT); }
    else if (this.ctx) { this.ctx.fillStyle = '#121214'; this.ctx.fillRect(0, 0, this.canvas.width, this.canvas.height); }
  }

  matrix() {
    const dpr = window.devicePixelRatio || 1;
    const w = Math.round(this.canvas.clientWidth * dpr), h = Math.round(this.canvas.clientHeight * dpr);
    if (this.canvas.width !== w || this.canvas.height !== h) { this.canvas.width = w; this.canvas.height = h; }
    const view = mul(translate(0, 0, -this.dist), mul(rotX(this.pitch), rotZ(this.yaw)));
    return mul(perspective(0.6, w / Math.max(h, 1), this.dist * 0.05, this.dist * 10), view);
  }

  draw() {
    if (!this.n) return;
    const m = this.matrix(), dpr = window.devicePixelRatio || 1;
    if (this.gl) {
      const gl = this.gl;
      gl.viewport(0, 0, this.canvas.width, this.canvas.height);
      gl.clearColor(0.07, 0.07, 0.08, 1); gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
      gl.enable(gl.DEPTH_TEST);
      gl.useProgram(this.prog);
      gl.uniformMatrix4fv(this.uMvp, false, new Float32Array(m));
      gl.bindBuffer(gl.ARRAY_BUFFER, this.bPos); gl.enableVertexAttribArray(this.aPos);
      gl.vertexAttribPointer(this.aPos, 3, gl.FLOAT, false, 0, 0);
      gl.bindBuffer(gl.ARRAY_BUFFER, this.bCol); gl.enableVertexAttribArray(this.aCol);
      gl.vertexAttribPointer(this.aCol, 3, gl.UNSIGNED_BYTE, true, 0, 0);
      gl.uniform1f(this.uSize, 5 * dpr);
      if (this.nBig) gl.drawArrays(gl.POINTS, 0, this.nBig);
      gl.uniform1f(this.uSize, 2.5 * dpr);
      gl.drawArrays(gl.POINTS, this.nBig, this.n - this.nBig);
      return;
    }
    // 2D: project, draw far to near
    const ctx = this.ctx, W = this.canvas.width, H = this.canvas.height, p = this.pos, c = this.col;
    ctx.fillStyle = '#121214'; ctx.fillRect(0, 0, W, H);
    const pts = [];
    for (let i = 0; i < this.n; i++) {
      const x = p[3 * i], y = p[3 * i + 1], z = p[3 * i + 2];
      const cx = m[0] * x + m[4] * y + m[8] * z + m[12], cy = m[1] * x + m[5] * y + m[9] * z + m[13];
      const cw = m[3] * x + m[7] * y + m[11] * z + m[15], cz = m[2] * x + m[6] * y + m[10] * z + m[14];
      if (cw <= 0) continue;
      pts.push([cz / cw, (cx / cw * 0.5 + 0.5) * W, (0.5 - cy / cw * 0.5) * H, i]);
    }
    pts.sort((a, b) => b[0] - a[0]);
    for (const [, sx, sy, i] of pts) {
      const s = (i < this.nBig ? 5 : 2.5) * dpr;
      ctx.fillStyle = `rgb(${c[3 * i]},${c[3 * i + 1]},${c[3 * i + 2]})`;
      ctx.fillRect(sx - s / 2, sy - s / 2, s, s);
    }
  }
}
