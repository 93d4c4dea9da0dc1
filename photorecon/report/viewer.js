
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
  // the textured model: its atlas unlit but for a little shading (the photos already hold the light)
  const texProg = program(`#version 300 es
    layout(location=0) in vec3 pos; layout(location=1) in vec2 uv; layout(location=2) in vec3 nrm;
    uniform mat4 mvp, mv; out vec2 vuv; out vec3 vn;
    void main() { vuv = uv; vn = mat3(mv) * nrm; gl_Position = mvp * vec4(pos, 1.0); }`,
    `#version 300 es
    precision highp float; in vec2 vuv; in vec3 vn; uniform sampler2D tex; uniform float ambient; uniform bool grey; out vec4 o;
    void main() {
      float d = abs(dot(normalize(vn), normalize(vec3(0.35, 0.45, 1.0))));
      o = vec4((grey ? vec3(0.75) : texture(tex, vuv).rgb) * (ambient + (1.0 - ambient) * d), 1.0);
    }`);
  const lineProg = program(`#version 300 es
    layout(location=0) in vec3 pos; uniform mat4 mvp; void main() { gl_Position = mvp * vec4(pos, 1.0); }`,
    `#version 300 es
    precision highp float; uniform vec3 color; out vec4 o; void main() { o = vec4(color, 1.0); }`);
  // --- state ---
  let nIdx = 0, meshVao = null, lineVao = null, showCams = meta.cameras > 0, colors = meta.colored, target, dist, az, el, dirty = true;
  const M = meta.model;   // the textured model (model.glb), when the page holds it
  let modelVao = null, modelTex = [], showModel = !!M;
  if (M) colors = true;
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
    if (showModel && modelVao) {
      gl.useProgram(texProg);
      gl.uniformMatrix4fv(gl.getUniformLocation(texProg, 'mvp'), false, mvp);
      gl.uniformMatrix4fv(gl.getUniformLocation(texProg, 'mv'), false, mv);
      gl.uniform1f(gl.getUniformLocation(texProg, 'ambient'), colors ? 0.8 : 0.25);
      gl.uniform1i(gl.getUniformLocation(texProg, 'grey'), colors ? 0 : 1);
      gl.uniform1i(gl.getUniformLocation(texProg, 'tex'), 0);
      gl.activeTexture(gl.TEXTURE0);
      gl.bindVertexArray(modelVao);
      for (const g of M.groups) {
        gl.bindTexture(gl.TEXTURE_2D, modelTex[g.texture]);
        gl.drawElements(gl.TRIANGLES, g.count * 3, gl.UNSIGNED_INT, g.start * 12);
      }
    } else if (meshVao) {
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
    canvas.dataset.state = 'drawn'; canvas.dataset.shown = showModel && modelVao ? 'model' : 'mesh';
  }
  function frame() { if (dirty) draw(); requestAnimationFrame(frame); }
  // --- data: base64 -> zlib inflate -> faces | positions | colours ---
  function bytesOf(id) {
    const bin = atob(document.getElementById(id).textContent.trim()), bytes = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
    return bytes;
  }
  const inflate = async id => new Response(new Blob([bytesOf(id)]).stream().pipeThrough(new DecompressionStream('deflate'))).arrayBuffer();
  const attr = (loc, data, size, type, normalized) => {
    gl.bindBuffer(gl.ARRAY_BUFFER, gl.createBuffer()); gl.bufferData(gl.ARRAY_BUFFER, data, gl.STATIC_DRAW);
    gl.enableVertexAttribArray(loc); gl.vertexAttribPointer(loc, size, type, normalized, 0, 0);
  };
  function normals(idx, pos, nv, key) {   // area-weighted vertex normals; vertices with one key share theirs
    const nrm = new Float32Array(nv * 3), rep = new Uint32Array(nv), first = new Map();
    for (let i = 0; i < nv; i++) {
      if (!key) { rep[i] = i; continue; }
      const k = key(i), r = first.get(k);
      if (r === undefined) { first.set(k, i); rep[i] = i; } else rep[i] = r;
    }
    for (let f = 0; f < idx.length; f += 3) {
      const a = idx[f] * 3, b = idx[f + 1] * 3, c = idx[f + 2] * 3;
      const ux = pos[b] - pos[a], uy = pos[b + 1] - pos[a + 1], uz = pos[b + 2] - pos[a + 2];
      const vx = pos[c] - pos[a], vy = pos[c + 1] - pos[a + 1], vz = pos[c + 2] - pos[a + 2];
      const nx = uy * vz - uz * vy, ny = uz * vx - ux * vz, nz = ux * vy - uy * vx;
      for (const v of [idx[f], idx[f + 1], idx[f + 2]]) { const k = rep[v] * 3; nrm[k] += nx; nrm[k + 1] += ny; nrm[k + 2] += nz; }
    }
    for (let i = 0; i < nv; i++) if (rep[i] !== i) for (let j = 0; j < 3; j++) nrm[i * 3 + j] = nrm[rep[i] * 3 + j];
    return nrm;
  }
  // the textured model: faces | positions | UVs (image order), one atlas per group of faces, each a JPEG; the
  // texture seams' vertices (same position, two UVs) share one normal
  async function loadModel() {
    const buf = await inflate('prv-model-data'), nf = M.faces, nv = M.vertices;
    const idx = new Uint32Array(buf, 0, nf * 3), q = new Uint16Array(buf, nf * 12, nv * 3);
    const uvq = new Uint16Array(buf, nf * 12 + nv * 6, nv * 2);
    const pos = new Float32Array(nv * 3), uv = new Float32Array(nv * 2);
    for (let i = 0; i < nv * 3; i++) pos[i] = M.offset[i % 3] + q[i] * M.step;
    for (let i = 0; i < nv * 2; i++) uv[i] = uvq[i] / 65535;
    const nrm = normals(idx, pos, nv, i => (q[i * 3] * 65536 + q[i * 3 + 1]) * 65536 + q[i * 3 + 2]);
    const tex = [];
    for (let t = 0; t < M.textures.length; t++) {
      const img = new Image();
      img.src = 'data:image/jpeg;base64,' + document.getElementById('prv-model-tex-' + t).textContent.trim();
      await img.decode();
      const k = gl.createTexture(); gl.bindTexture(gl.TEXTURE_2D, k);
      gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA, gl.RGBA, gl.UNSIGNED_BYTE, img);
      gl.generateMipmap(gl.TEXTURE_2D);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.LINEAR_MIPMAP_LINEAR);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.LINEAR);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE); gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
      tex.push(k);
    }
    const vao = gl.createVertexArray(); gl.bindVertexArray(vao);
    attr(0, pos, 3, gl.FLOAT, false); attr(1, uv, 2, gl.FLOAT, false); attr(2, nrm, 3, gl.FLOAT, false);
    gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, gl.createBuffer()); gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, idx, gl.STATIC_DRAW);
    gl.bindVertexArray(null);
    modelTex = tex; modelVao = vao;
  }
  async function load() {
    const buf = await inflate('prv-data');
    const nf = meta.faces, nv = meta.vertices;
    const idx = new Uint32Array(buf, 0, nf * 3), q = new Uint16Array(buf, nf * 12, nv * 3);
    const col = new Uint8Array(buf, nf * 12 + nv * 6, nv * 3);
    const pos = new Float32Array(nv * 3);
    for (let i = 0; i < nv * 3; i++) pos[i] = meta.offset[i % 3] + q[i] * meta.step;
    const nrm = normals(idx, pos, nv, null);
    meshVao = gl.createVertexArray(); gl.bindVertexArray(meshVao);
    attr(0, pos, 3, gl.FLOAT, false); attr(1, col, 3, gl.UNSIGNED_BYTE, true); attr(2, nrm, 3, gl.FLOAT, false);
    gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, gl.createBuffer()); gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, idx, gl.STATIC_DRAW);
    nIdx = nf * 3;
    if (meta.frusta.length) {
      lineVao = gl.createVertexArray(); gl.bindVertexArray(lineVao); attr(0, new Float32Array(meta.frusta), 3, gl.FLOAT, false);
    }
    gl.bindVertexArray(null);
    if (M) {
      try { await loadModel(); } catch (err) { showModel = false; setShown(false); msg('Could not load the textured model: ' + err); }
    }
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
  function setShown(model) {   // the toggle: the textured model or the mesh with its vertex colours
    showModel = model && !!M;
    colors = showModel || meta.colored;
    for (const [id, on] of [['prv-show-model', showModel], ['prv-show-mesh', !showModel]]) {
      const b = document.getElementById(id); if (b) b.setAttribute('aria-pressed', on ? 'true' : 'false');
    }
    dirty = true;
  }
  if (M) {
    document.getElementById('prv-show-model').onclick = () => setShown(true);
    document.getElementById('prv-show-mesh').onclick = () => setShown(false);
  }
  document.getElementById('prv-cams').onclick = () => { showCams = !showCams; dirty = true; };
  window.addEventListener('resize', () => { dirty = true; });
  const full = document.getElementById('prv-full');
  const onHash = () => { dirty = true; if (full) { const on = location.hash === '#viewer'; full.href = on ? '#' : '#viewer'; full.textContent = on ? 'close full window' : 'full window'; document.body.style.overflow = on ? 'hidden' : ''; } };
  window.addEventListener('hashchange', onHash); onHash();
  reset();
  load().then(() => requestAnimationFrame(frame), err => msg('Could not load the mesh: ' + err));
})();
