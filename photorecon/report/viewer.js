
(function () {
  const canvas = document.getElementById('prv-canvas');
  const msg = t => { document.getElementById('prv-msg').textContent = t; canvas.dataset.state = 'error'; };
  const meta = JSON.parse(document.getElementById('prv-meta').textContent);
  const gl = canvas.getContext('webgl2', {antialias: true, preserveDrawingBuffer: true});
  if (!gl) { msg('This browser has no WebGL2: the 3D view needs it (the images below show the result).'); return; }
  if (typeof DecompressionStream === 'undefined') { msg('This browser cannot inflate the embedded mesh (no DecompressionStream).'); return; }
  const V = meta.view;
  // --- small vector / matrix helpers (column-major 4x4, as WebGL wants) ---
  const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]], add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
  const mul = (a, s) => [a[0] * s, a[1] * s, a[2] * s], dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
  const norm = a => mul(a, 1 / Math.hypot(a[0], a[1], a[2]));
  function lookAt(eye, c, up) {
    const z = norm(sub(eye, c)), x = norm(cross(up, z)), y = cross(z, x);
    return [x[0], y[0], z[0], 0, x[1], y[1], z[1], 0, x[2], y[2], z[2], 0, -dot(x, eye), -dot(y, eye), -dot(z, eye), 1];
  }
  function perspective(fovy, aspect, n, f) {
    const t = 1 / Math.tan(fovy / 2);
    return [t / aspect, 0, 0, 0, 0, t, 0, 0, 0, 0, (f + n) / (n - f), -1, 0, 0, 2 * f * n / (n - f), 0];
  }
  function mat(a, b) {
    const o = new Array(16);
    for (let c = 0; c < 4; c++) for (let r = 0; r < 4; r++) {
      let s = 0; for (let k = 0; k < 4; k++) s += a[k * 4 + r] * b[c * 4 + k]; o[c * 4 + r] = s;
    }
    return o;
  }
  // --- shaders ---
  function program(vs, fs) {
    const p = gl.createProgram();
    for (const [type, src] of [[gl.VERTEX_SHADER, vs], [gl.FRAGMENT_SHADER, fs]]) {
      const s = gl.createShader(type); gl.shaderSource(s, src); gl.compileShader(s);
      if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
      gl.attachShader(p, s);
    }
    gl.linkProgram(p);
    if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(p));
    return p;
  }
  const meshProg = program(`#version 300 es
    layout(location=0) in vec3 pos; layout(location=1) in vec3 col; layout(location=2) in vec3 nrm;
    uniform mat4 mvp, mv; out vec3 vcol, vn;
    void main() { vcol = col; vn = mat3(mv) * nrm; gl_Position = mvp * vec4(pos, 1.0); }`,
    `#version 300 es
    precision highp float; in vec3 vcol, vn; uniform float ambient; uniform bool grey; out vec4 o;
    void main() {
      vec3 n = normalize(vn);
      float d = abs(dot(n, normalize(vec3(0.35, 0.45, 1.0))));   // a light near the eye; two-sided
      o = vec4((grey ? vec3(0.75) : vcol) * (ambient + (1.0 - ambient) * d), 1.0);
    }`);
  const lineProg = program(`#version 300 es
    layout(location=0) in vec3 pos; uniform mat4 mvp; void main() { gl_Position = mvp * vec4(pos, 1.0); }`,
    `#version 300 es
    precision highp float; uniform vec3 color; out vec4 o; void main() { o = vec4(color, 1.0); }`);
  // --- state ---
  let nIdx = 0, meshVao = null, lineVao = null, showCams = meta.cameras > 0, colors = meta.colored, target, dist, az, el, dirty = true;
  const up = norm(V.up), e1 = norm(V.front), e2 = cross(up, e1);
  const fovy = V.fov_deg * Math.PI / 180;
  function fitDistance(radius) {
    const aspect = canvas.clientWidth / Math.max(1, canvas.clientHeight);
    const fovMin = Math.min(fovy, 2 * Math.atan(Math.tan(fovy / 2) * aspect));
    return radius / Math.sin(fovMin / 2) * 1.05;
  }
  function reset() { target = V.target.slice(); dist = fitDistance(V.radius); az = 0; el = V.elevation_deg * Math.PI / 180; dirty = true; }
  function fitCameras() {
    let r = V.radius;
    for (const c of meta.camera_centers) r = Math.max(r, Math.hypot(...sub(c, V.target)) * 1.1);
    target = V.target.slice(); dist = fitDistance(r); dirty = true;
  }
  function eyeDir() {
    return add(mul(add(mul(e1, Math.cos(az)), mul(e2, Math.sin(az))), Math.cos(el)), mul(up, Math.sin(el)));
  }
  function draw() {
    dirty = false;
    const w = Math.max(1, Math.round(canvas.clientWidth * devicePixelRatio)), h = Math.max(1, Math.round(canvas.clientHeight * devicePixelRatio));
    if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
    gl.viewport(0, 0, w, h);
    gl.clearColor(0.933, 0.941, 0.953, 1); gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    const eye = add(target, mul(eyeDir(), dist));
    let far = dist + 2 * V.radius;
    if (showCams) for (const c of meta.camera_centers) far = Math.max(far, Math.hypot(...sub(c, eye)) + 0.2 * V.radius);
    let near = dist - 1.5 * V.radius;   // in front of the mesh and of every camera drawn
    if (showCams) for (const c of meta.camera_centers) near = Math.min(near, Math.hypot(...sub(c, eye)) - 1.5 * meta.frustum_scale);
    near = Math.max(near, far / 2000);
    const mv = lookAt(eye, target, up), mvp = mat(perspective(fovy, w / h, near, far), mv);
    gl.enable(gl.DEPTH_TEST);
    if (meshVao) {
      gl.useProgram(meshProg);
      gl.uniformMatrix4fv(gl.getUniformLocation(meshProg, 'mvp'), false, mvp);
      gl.uniformMatrix4fv(gl.getUniformLocation(meshProg, 'mv'), false, mv);
      gl.uniform1f(gl.getUniformLocation(meshProg, 'ambient'), colors ? 0.55 : 0.25);
      gl.uniform1i(gl.getUniformLocation(meshProg, 'grey'), colors ? 0 : 1);
      gl.bindVertexArray(meshVao); gl.drawElements(gl.TRIANGLES, nIdx, gl.UNSIGNED_INT, 0);
    }
    if (showCams && lineVao) {
      gl.useProgram(lineProg);
      gl.uniformMatrix4fv(gl.getUniformLocation(lineProg, 'mvp'), false, mvp);
      gl.uniform3f(gl.getUniformLocation(lineProg, 'color'), 0.86, 0.16, 0.16);
      gl.bindVertexArray(lineVao); gl.drawArrays(gl.LINES, 0, meta.frusta.length / 3);
    }
    gl.bindVertexArray(null);
    canvas.dataset.state = 'drawn';
  }
  function frame() { if (dirty) draw(); requestAnimationFrame(frame); }
  // --- data: base64 -> zlib inflate -> faces | positions | colours ---
  async function load() {
    const b64 = document.getElementById('prv-data').textContent.trim(), bin = atob(b64);
    const bytes = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
    const buf = await new Response(new Blob([bytes]).stream().pipeThrough(new DecompressionStream('deflate'))).arrayBuffer();
    const nf = meta.faces, nv = meta.vertices;
    const idx = new Uint32Array(buf, 0, nf * 3), q = new Uint16Array(buf, nf * 12, nv * 3);
    const col = new Uint8Array(buf, nf * 12 + nv * 6, nv * 3);
    const pos = new Float32Array(nv * 3), nrm = new Float32Array(nv * 3);
    for (let i = 0; i < nv * 3; i++) pos[i] = meta.offset[i % 3] + q[i] * meta.step;
    for (let f = 0; f < nf * 3; f += 3) {   // area-weighted vertex normals
      const a = idx[f] * 3, b = idx[f + 1] * 3, c = idx[f + 2] * 3;
      const ux = pos[b] - pos[a], uy = pos[b + 1] - pos[a + 1], uz = pos[b + 2] - pos[a + 2];
      const vx = pos[c] - pos[a], vy = pos[c + 1] - pos[a + 1], vz = pos[c + 2] - pos[a + 2];
      const nx = uy * vz - uz * vy, ny = uz * vx - ux * vz, nz = ux * vy - uy * vx;
      for (const k of [a, b, c]) { nrm[k] += nx; nrm[k + 1] += ny; nrm[k + 2] += nz; }
    }
    meshVao = gl.createVertexArray(); gl.bindVertexArray(meshVao);
    const attr = (loc, data, type, normalized) => {
      gl.bindBuffer(gl.ARRAY_BUFFER, gl.createBuffer()); gl.bufferData(gl.ARRAY_BUFFER, data, gl.STATIC_DRAW);
      gl.enableVertexAttribArray(loc); gl.vertexAttribPointer(loc, 3, type, normalized, 0, 0);
    };
    attr(0, pos, gl.FLOAT, false); attr(1, col, gl.UNSIGNED_BYTE, true); attr(2, nrm, gl.FLOAT, false);
    gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, gl.createBuffer()); gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, idx, gl.STATIC_DRAW);
    nIdx = nf * 3;
    if (meta.frusta.length) {
      lineVao = gl.createVertexArray(); gl.bindVertexArray(lineVao); attr(0, new Float32Array(meta.frusta), gl.FLOAT, false);
    }
    gl.bindVertexArray(null);
    dirty = true;
  }
  // --- interaction: pointer events cover mouse, pen and touch ---
  const pts = new Map(); let last = null;
  function pan(dx, dy) {
    const s = 2 * dist * Math.tan(fovy / 2) / Math.max(1, canvas.clientHeight), d = eyeDir();
    const right = norm(cross(up, d)), u = cross(d, right);
    target = add(target, add(mul(right, -dx * s), mul(u, dy * s))); dirty = true;
  }
  function rotate(dx, dy) {
    az -= dx * 0.008; el = Math.max(-1.55, Math.min(1.55, el + dy * 0.008)); dirty = true;
  }
  function pinchState() {
    const p = [...pts.values()];
    return {mid: [(p[0].x + p[1].x) / 2, (p[0].y + p[1].y) / 2], d: Math.hypot(p[0].x - p[1].x, p[0].y - p[1].y)};
  }
  canvas.addEventListener('pointerdown', e => {
    canvas.setPointerCapture(e.pointerId); pts.set(e.pointerId, {x: e.clientX, y: e.clientY, button: e.button, shift: e.shiftKey});
    last = pts.size === 2 ? pinchState() : null;
  });
  canvas.addEventListener('pointermove', e => {
    const p = pts.get(e.pointerId); if (!p) return;
    const dx = e.clientX - p.x, dy = e.clientY - p.y; p.x = e.clientX; p.y = e.clientY;
    if (pts.size === 1) { (p.button === 2 || p.button === 1 || e.shiftKey) ? pan(dx, dy) : rotate(dx, dy); }
    else if (pts.size === 2) {
      const s = pinchState();
      if (last) { dist *= last.d / Math.max(1, s.d); pan(s.mid[0] - last.mid[0], s.mid[1] - last.mid[1]); }
      last = s;
    }
  });
  const release = e => { pts.delete(e.pointerId); last = pts.size === 2 ? pinchState() : null; };
  canvas.addEventListener('pointerup', release); canvas.addEventListener('pointercancel', release);
  canvas.addEventListener('contextmenu', e => e.preventDefault());
  canvas.addEventListener('wheel', e => { e.preventDefault(); dist *= Math.exp(e.deltaY * 0.0015); dirty = true; }, {passive: false});
  canvas.addEventListener('dblclick', reset);
  document.getElementById('prv-reset').onclick = reset;
  document.getElementById('prv-fitcams').onclick = fitCameras;
  document.getElementById('prv-colors').onclick = () => { colors = !colors; dirty = true; };
  document.getElementById('prv-cams').onclick = () => { showCams = !showCams; dirty = true; };
  window.addEventListener('resize', () => { dirty = true; });
  const full = document.getElementById('prv-full');
  const onHash = () => { dirty = true; if (full) { const on = location.hash === '#viewer'; full.href = on ? '#' : '#viewer'; full.textContent = on ? 'close full window' : 'full window'; document.body.style.overflow = on ? 'hidden' : ''; } };
  window.addEventListener('hashchange', onHash); onHash();
  reset();
  load().then(() => requestAnimationFrame(frame), err => msg('Could not load the mesh: ' + err));
})();
