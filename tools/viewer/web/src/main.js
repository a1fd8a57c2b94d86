// Tactus live view: the deformed organ surface (coloured by displacement or stress), the
// instrument, the contacts with their force arrows, and live panels, fed by tactus-viewer over a
// WebSocket. Read-only: the page never sends anything that changes the simulation.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { decode, MSG_TOPOLOGY, MSG_FRAME, FLAG_HAS_TOOL, FLAG_HAS_STRESS, TOOL_GRASPER }
  from './protocol.js';
import { ForcePlot, drawHistogram } from './panels.js';

const $ = (id) => document.getElementById(id);
const MAX_CONTACTS_DRAWN = 512;

// ---- renderer, camera, lights ---------------------------------------------------------------
const container = $('view');
const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
renderer.setPixelRatio(window.devicePixelRatio);
container.appendChild(renderer.domElement);
const scene = new THREE.Scene();
scene.background = new THREE.Color(0x1d2127);
const camera = new THREE.PerspectiveCamera(40, 1, 0.001, 20);
camera.up.set(0, 0, 1);
camera.position.set(0.35, -0.35, 0.25);
const controls = new OrbitControls(camera, renderer.domElement);
controls.enableDamping = false;
controls.addEventListener('change', () => requestRender());
scene.add(new THREE.HemisphereLight(0xffffff, 0x404050, 1.6));
const sun = new THREE.DirectionalLight(0xffffff, 1.8);
sun.position.set(0.5, -0.8, 1.2);
scene.add(sun);

// ---- organ surface ---------------------------------------------------------------------------
const organMaterial = new THREE.MeshStandardMaterial({
  vertexColors: true, roughness: 0.55, metalness: 0.0, side: THREE.DoubleSide });
let organ = null;             // THREE.Mesh
let topologyGeneration = -1;
let cameraFitted = false;

function setTopology(t) {
  if (organ) {
    scene.remove(organ);
    organ.geometry.dispose();
  }
  const g = new THREE.BufferGeometry();
  const pos = new THREE.BufferAttribute(new Float32Array(3 * t.vertexCount), 3);
  pos.setUsage(THREE.DynamicDrawUsage);
  const col = new THREE.BufferAttribute(new Float32Array(3 * t.vertexCount), 3);
  col.setUsage(THREE.DynamicDrawUsage);
  g.setAttribute('position', pos);
  g.setAttribute('color', col);
  g.setIndex(new THREE.BufferAttribute(new Uint32Array(t.indices), 1));
  organ = new THREE.Mesh(g, organMaterial);
  organ.visible = false;              // until the first frame fills the positions
  scene.add(organ);
  topologyGeneration = t.generation;
}

// inferno-like ramp: dark purple -> red -> orange -> pale yellow
const RAMP = [[0.16, 0.07, 0.28], [0.50, 0.12, 0.40], [0.82, 0.28, 0.24], [0.97, 0.62, 0.13],
  [0.99, 0.96, 0.62]];
function ramp(t, out, o) {
  const x = Math.min(Math.max(t, 0), 1) * (RAMP.length - 1);
  const i = Math.min(Math.floor(x), RAMP.length - 2);
  const f = x - i;
  for (let k = 0; k < 3; ++k) out[o + k] = RAMP[i][k] * (1 - f) + RAMP[i + 1][k] * f;
}
const scaleEl = $('scale');
scaleEl.style.background = 'linear-gradient(to right,' +
  RAMP.map((c) => `rgb(${c.map((v) => Math.round(255 * v)).join(',')})`).join(',') + ')';

let colourRange = { displacement: 1e-3, stress: 1e3 };
function updateOrgan(fr) {
  if (!organ || fr.vertexCount * 3 !== organ.geometry.attributes.position.array.length) return;
  const pos = organ.geometry.attributes.position;
  pos.array.set(fr.positions);
  pos.needsUpdate = true;
  const mode = $('colour').value === 'stress' && (fr.flags & FLAG_HAS_STRESS) ? 'stress'
    : 'displacement';
  const values = mode === 'stress' ? fr.stress : fr.displacement;
  const frameMax = mode === 'stress' ? fr.maxStress : fr.maxDisplacement;
  // a range that grows at once and shrinks slowly, so colours do not flicker
  const floor = mode === 'stress' ? 100 : 1e-4;
  colourRange[mode] = Math.max(floor, frameMax, colourRange[mode] * 0.995);
  const col = organ.geometry.attributes.color;
  const inv = 1 / colourRange[mode];
  for (let i = 0; i < fr.vertexCount; ++i) ramp(0.08 + 0.92 * values[i] * inv, col.array, 3 * i);
  col.needsUpdate = true;
  organ.geometry.computeVertexNormals();
  organ.geometry.computeBoundingSphere();
  organ.visible = true;
  $('scaleLabel').textContent = mode === 'stress'
    ? `von Mises 0 … ${(colourRange.stress / 1e3).toFixed(1)} kPa`
    : `displacement 0 … ${(colourRange.displacement * 1e3).toFixed(1)} mm`;
  if (!cameraFitted) fitCamera();
}

function fitCamera() {
  const s = organ.geometry.boundingSphere;
  if (!s || !(s.radius > 0)) return;
  controls.target.copy(s.center);
  const dir = new THREE.Vector3(0.55, -0.75, 0.45).normalize();
  camera.position.copy(s.center).addScaledVector(dir, s.radius * 2.6);
  camera.near = s.radius / 100;
  camera.far = s.radius * 100;
  camera.updateProjectionMatrix();
  controls.update();
  cameraFitted = true;
}

// ---- instrument ------------------------------------------------------------------------------
const toolMaterial = new THREE.MeshStandardMaterial({ color: 0xb8c2cc, metalness: 0.7, roughness: 0.3 });
const unitCylinder = new THREE.CylinderGeometry(1, 1, 1, 20, 1, true);
const unitSphere = new THREE.SphereGeometry(1, 20, 14);
const toolGroup = new THREE.Group();
scene.add(toolGroup);
const toolPool = [];
const Y = new THREE.Vector3(0, 1, 0);

function toolPart(i) {
  while (toolPool.length <= i) {
    const part = new THREE.Group();
    part.add(new THREE.Mesh(unitCylinder, toolMaterial));
    part.add(new THREE.Mesh(unitSphere, toolMaterial));
    part.add(new THREE.Mesh(unitSphere, toolMaterial));
    toolGroup.add(part);
    toolPool.push(part);
  }
  return toolPool[i];
}

function updateTool(fr) {
  let used = 0;
  if (fr.flags & FLAG_HAS_TOOL) {
    const p = fr.primitives;
    const a = new THREE.Vector3(), b = new THREE.Vector3(), d = new THREE.Vector3();
    for (let i = 0; i < fr.primitiveCount; ++i) {
      a.set(p[8 * i], p[8 * i + 1], p[8 * i + 2]);
      b.set(p[8 * i + 3], p[8 * i + 4], p[8 * i + 5]);
      const r = p[8 * i + 6];
      d.subVectors(b, a);
      const len = d.length();
      // a grasper's jaw samples are spheres inside its capsules: draw the capsules only
      if (len < 1e-9 && fr.toolType === TOOL_GRASPER) continue;
      const part = toolPart(used++);
      part.visible = true;
      const [cyl, s0, s1] = part.children;
      s0.position.copy(a); s0.scale.setScalar(r);
      s1.position.copy(b); s1.scale.setScalar(r);
      cyl.visible = len > 1e-9;
      if (cyl.visible) {
        cyl.position.addVectors(a, b).multiplyScalar(0.5);
        cyl.quaternion.setFromUnitVectors(Y, d.clone().normalize());
        cyl.scale.set(r, len, r);
      }
    }
  }
  for (let i = used; i < toolPool.length; ++i) toolPool[i].visible = false;
}

// ---- contacts and force arrows -----------------------------------------------------------------
const contactDots = new THREE.InstancedMesh(new THREE.SphereGeometry(1, 10, 8),
  new THREE.MeshBasicMaterial({ color: 0x7cf0ff }), MAX_CONTACTS_DRAWN);
contactDots.count = 0;
scene.add(contactDots);
const arrowGroup = new THREE.Group();
scene.add(arrowGroup);
const arrows = [];
const toolArrow = new THREE.ArrowHelper(new THREE.Vector3(0, 0, 1), new THREE.Vector3(), 0.01, 0xffb347);
scene.add(toolArrow);
let arrowScale = 0.1;   // N for the longest contact arrow (smoothed)
let toolArrowScale = 0.1;

function updateContacts(fr, sceneSize) {
  const n = Math.min(fr.contactCount, MAX_CONTACTS_DRAWN);
  const m = new THREE.Matrix4();
  const dot = sceneSize * 0.006;
  let fmax = 0;
  for (let i = 0; i < n; ++i) {
    const f = fr.contactForces;
    fmax = Math.max(fmax, Math.hypot(f[3 * i], f[3 * i + 1], f[3 * i + 2]));
  }
  const toolF = Math.hypot(...fr.toolForce);
  arrowScale = Math.max(1e-3, fmax, arrowScale * 0.99);
  toolArrowScale = Math.max(1e-3, toolF, toolArrowScale * 0.99);
  const longest = sceneSize * 0.25;
  const show = $('arrows').checked;
  const o = new THREE.Vector3(), d = new THREE.Vector3();
  for (let i = 0; i < n; ++i) {
    const c = fr.contactPoints, f = fr.contactForces;
    m.makeScale(dot, dot, dot).setPosition(c[3 * i], c[3 * i + 1], c[3 * i + 2]);
    contactDots.setMatrixAt(i, m);
    while (arrows.length <= i) {
      const a = new THREE.ArrowHelper(new THREE.Vector3(0, 0, 1), new THREE.Vector3(), 0.01, 0x7cf0ff);
      arrowGroup.add(a);
      arrows.push(a);
    }
    d.set(f[3 * i], f[3 * i + 1], f[3 * i + 2]);
    const mag = d.length();
    const a = arrows[i];
    a.visible = show && mag > 1e-6;
    if (a.visible) {
      // the arrow ends at the contact point: the tool pushes the tissue along it
      const len = Math.max(longest * mag / arrowScale, dot * 2);
      d.normalize();
      o.set(c[3 * i], c[3 * i + 1], c[3 * i + 2]).addScaledVector(d, -len);
      a.position.copy(o);
      a.setDirection(d);
      a.setLength(len, len * 0.25, len * 0.12);
    }
  }
  for (let i = n; i < arrows.length; ++i) arrows[i].visible = false;
  contactDots.count = n;
  contactDots.instanceMatrix.needsUpdate = true;
  // the force rendered to the hand, drawn from the tool
  toolArrow.visible = show && (fr.flags & FLAG_HAS_TOOL) && toolF > 1e-4;
  if (toolArrow.visible) {
    d.set(...fr.toolForce).normalize();
    toolArrow.position.set(...fr.toolPos);
    toolArrow.setDirection(d);
    const len = longest * toolF / toolArrowScale;
    toolArrow.setLength(len, len * 0.25, len * 0.12);
  }
}

// ---- panels, connection ------------------------------------------------------------------------
const forcePlot = new ForcePlot($('forcePlot'));
const view = {                        // read by the browser test
  frames: 0, statusUpdates: 0, lastStatus: null, connected: false, attachCount: 0,
  reconnects: 0, topologyGeneration: -1, lastSeq: 0,
  organRect() {
    if (!organ || !organ.visible) return null;
    const a = organ.geometry.attributes.position.array;
    const r = renderer.domElement.getBoundingClientRect();
    let x0 = Infinity, y0 = Infinity, x1 = -Infinity, y1 = -Infinity;
    const v = new THREE.Vector3();
    for (let i = 0; i < a.length; i += 3) {
      v.set(a[i], a[i + 1], a[i + 2]).project(camera);
      const x = r.left + (v.x + 1) / 2 * r.width, y = r.top + (1 - v.y) / 2 * r.height;
      x0 = Math.min(x0, x); x1 = Math.max(x1, x); y0 = Math.min(y0, y); y1 = Math.max(y1, y);
    }
    return { x: x0, y: y0, width: x1 - x0, height: y1 - y0 };
  },
};
window.tactusView = view;

let banner = { text: '', kind: '' };
let restartNoteUntil = 0;
function setBanner(text, kind = 'bad') {
  const el = $('banner');
  if (!text) { el.className = 'banner hidden'; return; }
  el.className = 'banner ' + kind;
  el.style.background = kind === 'ok' ? '#2f7d4a' : kind === 'warn' ? '#8a6d1f' : '#9a3b3b';
  el.textContent = text;
  banner = { text, kind };
}

function onStatus(s) {
  view.statusUpdates++;
  view.lastStatus = s;
  const pill = $('conn');
  if (s.attach_count > view.attachCount && view.attachCount > 0) {
    restartNoteUntil = performance.now() + 4000;
  }
  view.attachCount = s.attach_count;
  const running = s.attached && s.state === 'running';
  pill.textContent = running ? 'live' : s.state;
  pill.className = 'pill ' + (running ? 'ok' : s.state === 'stalled' ? 'warn' : 'bad');
  $('status').textContent = s.message;
  if (!running) {
    setBanner(s.state === 'waiting' ? 'Waiting for the simulation…'
      : s.state === 'stalled' ? 'Simulation stalled' : 'Simulation stopped — waiting for it to restart');
  } else if (performance.now() < restartNoteUntil) {
    setBanner(`Simulation restarted — reconnected (generation ${s.generation})`, 'ok');
  } else {
    setBanner('');
  }
  const sim = s.sim || {};
  $('simHz').textContent = s.attached && sim.hz ? `${sim.hz.toFixed(1)} Hz` : '–';
  $('stepMs').textContent = sim.step_ms !== undefined ? `${sim.step_ms.toFixed(2)} ms` : '–';
  const h = s.haptic || {};
  $('hapticHz').textContent = h.active ? `${h.hz.toFixed(0)} Hz` : 'not running';
  $('contacts').textContent = sim.contacts !== undefined
    ? `${sim.contacts}${h.active ? ` (haptic ${h.contacts})` : ''}` : '–';
  $('force').textContent = h.active ? `${h.force_n.toFixed(3)} N`
    : sim.force_n !== undefined ? `${sim.force_n.toFixed(3)} N (sim)` : '–';
  const pe = h.period_error_us;
  $('p99').textContent = pe ? `${pe.p99.toFixed(1)} µs` : '–';
  if (h.force_series && s.now_s) {
    const now = performance.now() / 1e3;
    for (const [t, f] of h.force_series) forcePlot.addHaptic(now - (s.now_s - t), f);
  }
  drawHistogram($('histogram'), pe);
}

function onFrame(fr) {
  if (fr.topologyGeneration !== topologyGeneration) return;   // topology not received yet
  view.frames++;
  view.lastSeq = fr.seq;
  $('frames').textContent = `${view.frames} (#${fr.seq}, t = ${fr.simTime.toFixed(2)} s)`;
  updateOrgan(fr);
  const size = organ && organ.geometry.boundingSphere ? organ.geometry.boundingSphere.radius : 0.1;
  updateTool(fr);
  updateContacts(fr, size);
  forcePlot.addSim(performance.now() / 1e3, Math.hypot(...fr.toolForce));
  requestRender();
}

let ws = null;
let retryMs = 250;
function connect() {
  const url = `${location.protocol === 'https:' ? 'wss' : 'ws'}://${location.host}/ws`;
  ws = new WebSocket(url);
  ws.binaryType = 'arraybuffer';
  ws.onopen = () => {
    view.connected = true;
    retryMs = 250;
  };
  ws.onmessage = (ev) => {
    if (typeof ev.data === 'string') {
      try { onStatus(JSON.parse(ev.data)); } catch (e) { console.warn('bad status', e); }
      return;
    }
    const m = decode(ev.data);
    if (!m) return;
    if (m.kind === MSG_TOPOLOGY) {
      setTopology(m);
      view.topologyGeneration = m.generation;
    } else if (m.kind === MSG_FRAME) {
      onFrame(m);
    }
  };
  ws.onclose = () => {
    if (view.connected) view.reconnects++;
    view.connected = false;
    $('conn').textContent = 'offline';
    $('conn').className = 'pill bad';
    setBanner('Connection to the viewer lost — reconnecting…');
    setTimeout(connect, retryMs);
    retryMs = Math.min(retryMs * 2, 4000);
  };
}

// ---- render on demand ---------------------------------------------------------------------------
let renderQueued = false;
function requestRender() {
  if (renderQueued) return;
  renderQueued = true;
  requestAnimationFrame(() => {
    renderQueued = false;
    renderer.render(scene, camera);
  });
}
function resize() {
  const w = container.clientWidth, h = container.clientHeight;
  renderer.setSize(w, h);
  camera.aspect = w / Math.max(1, h);
  camera.updateProjectionMatrix();
  requestRender();
}
window.addEventListener('resize', resize);
$('colour').addEventListener('change', () => { colourRange = { displacement: 1e-3, stress: 1e3 }; });
setInterval(() => forcePlot.draw(performance.now() / 1e3), 100);
resize();
connect();
