// reachgrasp 3-D viewer: draws the scene the server computed (/ui/view/.../scene.json) with
// three.js. The server sends every shape in its link frame and every link's world pose per
// frame (its own FK, URDF collision and visual shapes), so this script only composes transforms; it
// computes no kinematics. World frame: the robot base, metres, z up; poses [x,y,z,qw,qx,qy,qz].
import * as THREE from './vendor/three.module.js';
import { OrbitControls } from './vendor/OrbitControls.js';

const COLORS = {
  background: 0xeef2f6, arm: 0x5a5f6e, hand: 0x1f77b4, object: 0xb07a3c, table: 0xd9cbb0,
  obstacle: 0xc0392b, contact: 0xd62728, velocity: 0x9467bd, force: 0x2ca02c,
  human: 0xe6a100, humanJoint: 0x8a5a00,
};

function setPose(obj, p, at = 0) {
  obj.position.set(p[at], p[at + 1], p[at + 2]);
  // JSON quaternions are [w, x, y, z]; three.js takes (x, y, z, w).
  obj.quaternion.set(p[at + 4], p[at + 5], p[at + 6], p[at + 3]);
}

function geometryOf(g) {
  switch (g.type) {
    case 'sphere': return new THREE.SphereGeometry(g.radius, 24, 16);
    case 'box': return new THREE.BoxGeometry(g.size[0], g.size[1], g.size[2]);
    case 'cylinder': return new THREE.CylinderGeometry(g.radius, g.radius, g.height, 28);
    case 'capsule': return new THREE.CapsuleGeometry(g.radius, g.length, 8, 24);
    case 'mesh': {
      const geo = new THREE.BufferGeometry();
      geo.setAttribute('position', new THREE.Float32BufferAttribute(g.vertices, 3));
      geo.setIndex(g.indices);
      geo.computeVertexNormals();
      return geo;
    }
    default: throw new Error(`unknown shape type ${g.type}`);
  }
}

function shapeMesh(s, material) {
  const m = new THREE.Mesh(geometryOf(s.geometry), material);
  setPose(m, s.pose);
  return m;
}

function lights(scene) {
  scene.add(new THREE.HemisphereLight(0xffffff, 0x8a8070, 2.0));
  const sun = new THREE.DirectionalLight(0xffffff, 1.6);
  sun.position.set(2, -1.5, 3);
  scene.add(sun);
}

// The support plane as a table top: a slab just below the plane, a square around the scene's
// footprint on it.
function table(support, center, radius) {
  const n = new THREE.Vector3(...support.normal).normalize();
  const c = new THREE.Vector3(...center);
  const onPlane = c.clone().addScaledVector(n, support.offset - n.dot(c));
  const side = Math.max(1.2, 2.4 * radius);
  const thick = 0.02;
  const slab = new THREE.Mesh(
    new THREE.BoxGeometry(side, side, thick),
    new THREE.MeshStandardMaterial({ color: COLORS.table, roughness: 0.9 }));
  slab.quaternion.setFromUnitVectors(new THREE.Vector3(0, 0, 1), n);
  slab.position.copy(onPlane).addScaledVector(n, -thick / 2);
  return slab;
}

function ellipsoidMesh(e) {
  const m = new THREE.Mesh(
    new THREE.SphereGeometry(1, 32, 16),
    new THREE.MeshBasicMaterial({ color: COLORS[e.kind] ?? COLORS.velocity, wireframe: true,
      transparent: true, opacity: 0.55 }));
  const [a, b, c] = e.axes.map((v) => new THREE.Vector3(...v));
  m.quaternion.setFromRotationMatrix(new THREE.Matrix4().makeBasis(a, b, c));
  m.scale.set(...e.semi_axes);
  m.position.set(...e.center);
  m.userData.kind = e.kind;
  return m;
}

// The static surroundings shared by the robot's and the human's side.
function surroundings(data) {
  const g = new THREE.Group();
  if (data.support) {
    g.add(table(data.support, data.center, data.radius));
  } else {
    // No support in the scene: a grid on the base plane (z = 0) keeps up and down readable.
    const grid = new THREE.GridHelper(2, 20, 0xb8c0ca, 0xd5dbe2);
    grid.rotation.x = Math.PI / 2;
    g.add(grid);
  }
  if (data.object) {
    g.add(shapeMesh(data.object, new THREE.MeshStandardMaterial({ color: COLORS.object, roughness: 0.6 })));
  }
  for (const o of data.obstacles) {
    g.add(shapeMesh(o, new THREE.MeshStandardMaterial({ color: COLORS.obstacle, transparent: true, opacity: 0.6 })));
  }
  return g;
}

// Each link carries its collision shapes and, where the URDF has them, its visual shapes, as
// two groups; showGeometry picks which one a link shows.
function robotLinks(data) {
  const arm = new THREE.MeshStandardMaterial({ color: COLORS.arm, roughness: 0.5, metalness: 0.2 });
  const hand = new THREE.MeshStandardMaterial({ color: COLORS.hand, roughness: 0.5 });
  return data.links.map((l) => {
    const group = new THREE.Group();
    group.name = l.name;
    const collision = new THREE.Group();
    for (const s of l.shapes) collision.add(shapeMesh(s, l.hand ? hand : arm));
    const visual = new THREE.Group();
    for (const s of l.visuals ?? []) visual.add(shapeMesh(s, l.hand ? hand : arm));
    group.add(collision, visual);
    group.userData = { collision, visual };
    return group;
  });
}

// 'visual': links with visual geometry show it, the others their collision shapes;
// 'collision': every link shows its collision shapes (what the collision checks use).
function showGeometry(links, mode) {
  for (const l of links) {
    const { collision, visual } = l.userData;
    const useVisual = mode === 'visual' && visual.children.length > 0;
    visual.visible = useVisual;
    collision.visible = !useVisual;
  }
}

function graspMarks(data) {
  const contacts = new THREE.Group();
  const dot = new THREE.MeshBasicMaterial({ color: COLORS.contact });
  for (const c of data.contacts) {
    const s = new THREE.Mesh(new THREE.SphereGeometry(0.006, 12, 8), dot);
    s.position.set(...c.point);
    contacts.add(s);
    contacts.add(new THREE.ArrowHelper(new THREE.Vector3(...c.normal), s.position.clone(), 0.05,
      COLORS.contact, 0.012, 0.008));
  }
  // One at a time (the select): velocity and force ellipsoids share axes and would hide each
  // other.
  const ellipsoids = new THREE.Group();
  for (const e of data.ellipsoids) {
    const m = ellipsoidMesh(e);
    m.visible = e.kind === 'velocity';
    ellipsoids.add(m);
  }
  return { contacts, ellipsoids };
}

// The demonstrator's arm: a ball per tracked point and a stick per segment, moved per frame.
function humanFigure(h) {
  const g = new THREE.Group();
  const jointMat = new THREE.MeshStandardMaterial({ color: COLORS.humanJoint });
  const boneMat = new THREE.MeshStandardMaterial({ color: COLORS.human });
  const balls = h.points.map((name) => {
    const r = name.endsWith('tip') ? 0.008 : 0.02;
    const b = new THREE.Mesh(new THREE.SphereGeometry(r, 16, 12), jointMat);
    g.add(b);
    return b;
  });
  const sticks = h.segments.map(([a]) => {
    const r = a === 2 ? 0.005 : 0.018;
    const s = new THREE.Mesh(new THREE.CylinderGeometry(r, r, 1, 12), boneMat);
    g.add(s);
    return s;
  });
  const up = new THREE.Vector3(0, 1, 0);
  const pa = new THREE.Vector3();
  const pb = new THREE.Vector3();
  const dir = new THREE.Vector3();
  g.userData.pose = (k) => {
    const f = h.frames[k];
    balls.forEach((b, i) => b.position.set(f[3 * i], f[3 * i + 1], f[3 * i + 2]));
    h.segments.forEach(([a, b], i) => {
      pa.set(f[3 * a], f[3 * a + 1], f[3 * a + 2]);
      pb.set(f[3 * b], f[3 * b + 1], f[3 * b + 2]);
      dir.subVectors(pb, pa);
      const len = Math.max(dir.length(), 1e-6);
      sticks[i].position.addVectors(pa, pb).multiplyScalar(0.5);
      sticks[i].quaternion.setFromUnitVectors(up, dir.divideScalar(len));
      sticks[i].scale.set(1, len, 1);
    });
  };
  return g;
}

async function start(root) {
  const t0 = performance.now();
  const canvas = root.querySelector('canvas');
  const errorBox = root.querySelector('.viewer-error');
  const state = { ready: false, frame: 0, renders: 0, liveUpdates: 0, firstFrameMs: null };
  root.viewer = state;
  window.reachgraspViewer = state;

  const res = await fetch(root.dataset.scene);
  if (!res.ok) {
    const text = await res.text();
    errorBox.textContent = `The scene could not be loaded (${res.status}): ${text.replace(/<[^>]+>/g, ' ').trim().slice(0, 300)}`;
    return;
  }
  const data = await res.json();
  state.fetchMs = performance.now() - t0;

  // preserveDrawingBuffer keeps the last frame readable (toDataURL) for tests and screenshots.
  const renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
  renderer.setPixelRatio(window.devicePixelRatio || 1);
  renderer.setClearColor(COLORS.background, 1);

  const robotScene = new THREE.Scene();
  lights(robotScene);
  robotScene.add(surroundings(data));
  const links = robotLinks(data);
  for (const l of links) robotScene.add(l);
  const hasVisuals = data.links.some((l) => (l.visuals ?? []).length > 0);
  const geometrySelect = root.querySelector('.viewer-geometry');
  geometrySelect.value = hasVisuals ? 'visual' : 'collision';
  geometrySelect.disabled = !hasVisuals;
  showGeometry(links, geometrySelect.value);
  const marks = graspMarks(data);
  robotScene.add(marks.contacts, marks.ellipsoids);

  // Fig. 2: the human on the left, the robot on the right, one camera, one clock.
  let humanScene = null;
  let human = null;
  if (data.human) {
    humanScene = new THREE.Scene();
    lights(humanScene);
    humanScene.add(surroundings(data));
    human = humanFigure(data.human);
    humanScene.add(human);
  }

  const camera = new THREE.PerspectiveCamera(40, 1, 0.01, 50);
  camera.up.set(0, 0, 1);
  const c = new THREE.Vector3(...data.center);
  const dist = data.radius / Math.sin(THREE.MathUtils.degToRad(20)) * 0.85;
  camera.position.copy(c).add(new THREE.Vector3(0.75, -0.55, 0.42).normalize().multiplyScalar(dist));
  const controls = new OrbitControls(camera, canvas);
  controls.target.copy(c);
  controls.update();

  const frames = data.frames;
  const n = frames.times.length;
  const duration = frames.times[n - 1];
  const slider = root.querySelector('.viewer-time');
  const readout = root.querySelector('.time-readout');
  const play = root.querySelector('.viewer-play');
  const step = root.querySelector('.viewer-step');
  const showEllipsoid = root.querySelector('.viewer-ellipsoid');
  const showContacts = root.querySelector('.viewer-contacts');
  const legend = root.querySelector('.viewer-legend');
  const linkLegend = () => (geometrySelect.value === 'visual'
    ? 'URDF visual geometry where the robot has it, collision shapes elsewhere'
    : 'URDF collision shapes');
  const setLegend = () => {
    legend.textContent = `${data.title}. Grey: arm links, blue: hand links (${linkLegend()})` +
      `${data.object ? ', brown: object' : ''}${data.support ? ' on its support' : ''}` +
      `${data.obstacles.length ? ', red: obstacles' : ''}${data.contacts.length ? ', red dots: contacts' : ''}` +
      `${data.ellipsoids.length ? ', purple/green: velocity/force ellipsoid of the arm at the grasp' : ''}` +
      `${data.human ? '. Left: the demonstrator (registered into the robot frame); right: the robot' : ''}.`;
  };
  setLegend();

  function resize() {
    const w = canvas.clientWidth;
    const h = canvas.clientHeight;
    if (canvas.width !== Math.round(w * renderer.getPixelRatio()) || canvas.height !== Math.round(h * renderer.getPixelRatio())) {
      renderer.setSize(w, h, false);
    }
    camera.aspect = (humanScene ? w / 2 : w) / h;
    camera.updateProjectionMatrix();
  }

  function render() {
    resize();
    const w = canvas.clientWidth;
    const h = canvas.clientHeight;
    if (humanScene) {
      renderer.setScissorTest(true);
      renderer.setViewport(0, 0, w / 2, h);
      renderer.setScissor(0, 0, w / 2, h);
      renderer.render(humanScene, camera);
      renderer.setViewport(w / 2, 0, w / 2, h);
      renderer.setScissor(w / 2, 0, w / 2, h);
      renderer.render(robotScene, camera);
      renderer.setScissorTest(false);
    } else {
      renderer.setViewport(0, 0, w, h);
      renderer.render(robotScene, camera);
    }
    state.renders += 1;
  }

  function poseLinks(poses) {
    links.forEach((l, i) => setPose(l, poses, 7 * i));
  }

  function show(k) {
    state.frame = Math.max(0, Math.min(n - 1, k));
    poseLinks(frames.links[state.frame]);
    if (human) human.userData.pose(state.frame);
    slider.value = String(state.frame);
    readout.textContent = `${frames.times[state.frame].toFixed(2)} / ${duration.toFixed(2)} s`;
    render();
  }

  let playing = false;
  let clockStart = 0;
  let timeStart = 0;
  function tick(now) {
    if (!playing) return;
    const t = timeStart + (now - clockStart) / 1000;
    // The frame whose time was reached last.
    let k = state.frame;
    while (k + 1 < n && frames.times[k + 1] <= t) k += 1;
    show(k);
    if (k >= n - 1) { setPlaying(false); return; }
    requestAnimationFrame(tick);
  }
  function setPlaying(on) {
    playing = on && n > 1;
    play.textContent = playing ? 'Pause' : 'Play';
    if (playing) {
      if (state.frame >= n - 1) show(0);
      clockStart = performance.now();
      timeStart = frames.times[state.frame];
      requestAnimationFrame(tick);
    }
  }

  slider.max = String(n - 1);
  for (const el of [slider, play, step]) el.disabled = n < 2;
  slider.addEventListener('input', () => { setPlaying(false); show(Number(slider.value)); });
  play.addEventListener('click', () => setPlaying(!playing));
  step.addEventListener('click', () => { setPlaying(false); show(state.frame + 1 >= n ? 0 : state.frame + 1); });
  showEllipsoid.disabled = !data.ellipsoids.length;
  showContacts.disabled = !data.contacts.length;
  showEllipsoid.addEventListener('change', () => {
    for (const m of marks.ellipsoids.children) m.visible = m.userData.kind === showEllipsoid.value;
    render();
  });
  geometrySelect.addEventListener('change', () => {
    showGeometry(links, geometrySelect.value);
    setLegend();
    render();
  });
  showContacts.addEventListener('change', () => { marks.contacts.visible = showContacts.checked; render(); });
  controls.addEventListener('change', render);
  window.addEventListener('resize', render);

  // ?t=<seconds> opens the motion at that time (a link to a moment of a plan).
  const tParam = Number(new URLSearchParams(window.location.search).get('t'));
  let first = 0;
  if (Number.isFinite(tParam) && tParam > 0) {
    while (first + 1 < n && frames.times[first + 1] <= tParam) first += 1;
  }
  show(first);
  state.firstFrameMs = performance.now() - t0;
  // performance.now() counts from the navigation's start: the whole wait a user sees.
  state.sinceNavigationMs = performance.now();
  state.frames = n;
  state.step = (k) => show(k);
  state.ready = true;
  root.dataset.ready = 'true';

  if (root.dataset.live) follow(root, data, state, poseLinks, render, readout);
}

// Live view: every execution event with a measured state poses the robot; the server turns
// the measured joint positions into link poses (its FK), in the scene's link order.
function follow(root, data, state, poseLinks, render, readout) {
  const events = new EventSource(root.dataset.live);
  let inFlight = false;
  let pending = null;
  async function pose(fb) {
    if (inFlight) { pending = fb; return; }
    inFlight = true;
    try {
      const res = await fetch(`/ui/view/robots/${encodeURIComponent(data.robot)}/pose`, {
        method: 'POST',
        headers: { 'content-type': 'application/json' },
        body: JSON.stringify({ joint_names: data.joint_names, positions: fb.positions }),
      });
      if (res.ok) {
        const { links } = await res.json();
        poseLinks(links);
        state.liveUpdates += 1;
        state.liveT = fb.t;
        readout.textContent = `live: ${fb.t.toFixed(2)} s, ${(100 * fb.progress).toFixed(0)} %`;
        root.dataset.liveUpdates = String(state.liveUpdates);
        render();
      }
    } finally {
      inFlight = false;
      if (pending) { const next = pending; pending = null; pose(next); }
    }
  }
  const onEvent = (e) => {
    const exec = JSON.parse(e.data);
    state.liveState = exec.state;
    root.dataset.liveState = exec.state;
    if (exec.last_feedback) pose(exec.last_feedback);
  };
  events.addEventListener('progress', onEvent);
  events.addEventListener('final', (e) => { onEvent(e); events.close(); });
}

for (const root of document.querySelectorAll('.viewer[data-scene]')) {
  start(root).catch((e) => {
    root.querySelector('.viewer-error').textContent = `The viewer failed: ${e.message}`;
  });
}
