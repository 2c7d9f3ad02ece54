// motiongen serve: the browser side. Shows the scene and the skinned body, plays the frames the
// server generates (the server's clock is the truth), and sends goals. Talks only to the JSON API
// of motiongen/serve/server.py; three.js comes from static/vendor/ through the import map.

import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';

const POLL_MS = 100;
const CLICK_SLOP_PX = 5;    // a pointer that moved further than this orbited: not a click
const LINE_LIFT = 0.03;     // route / markers sit this far above the floor (no z-fighting)
const CUT_HEIGHT = 1.2;     // "cut away" hides the scene above this height over the floor
const PALETTE = [0x4fc3f7, 0xffb74d, 0x81c784, 0xe57373, 0xba68c8, 0xfff176, 0x4db6ac, 0xf06292];

const $ = (id) => document.getElementById(id);
const ui = {
  action: $('action'), play: $('play'), clear: $('clear'), scrub: $('scrub'),
  scrubLabel: $('scrub-label'), status: $('status'), goals: $('goals'), error: $('error'),
  loading: $('loading'), cut: $('cut'),
};

// ---------------------------------------------------------------- HTTP

class ApiError extends Error {}   // the server's {"error": "..."} line

async function request(method, url, body) {
  const init = { method, headers: {} };
  if (body !== undefined) {
    init.headers['Content-Type'] = 'application/json';
    init.body = JSON.stringify(body);
  }
  const response = await fetch(url, init);
  let data = null;
  try {
    data = await response.json();
  } catch (err) {
    data = null;
  }
  if (!response.ok) {
    const message = (data && data.error) || `${method} ${url}: HTTP ${response.status}`;
    throw new ApiError(message);
  }
  return data;
}

// ---------------------------------------------------------------- state

let info = null;            // GET /api/info
let fps = 30;
let bones = [];             // body bones in info.joint_names order
let rootBone = null;        // the one whose parent is -1: it gets the root translation
const motion = { rev: null, root: [], quats: [], joints: [] };  // frames 0..n-1 from /api/frames
let server = null;          // last applied /api/state
let stateSeq = 0;           // requests are numbered when sent; older answers are dropped
let appliedSeq = 0;
let clock = { frame: 0, at: 0, playing: false };  // server play head at local time `at`
let scrubFrame = null;      // frame chosen with the slider (paused), or null: follow the play head
let shown = -1;             // frame the body shows
let lastLive = -1;          // last frame shown from the live play head
let goalsKey = '';
let routeKey = '';
let errorIsConnection = false;

// ---------------------------------------------------------------- three.js scene

const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
renderer.setSize(window.innerWidth, window.innerHeight);
renderer.localClippingEnabled = true;
$('view').appendChild(renderer.domElement);

const scene = new THREE.Scene();
scene.background = new THREE.Color(0x2b3038);
const camera = new THREE.PerspectiveCamera(50, window.innerWidth / window.innerHeight, 0.05, 500);
const controls = new OrbitControls(camera, renderer.domElement);
controls.enableDamping = true;
controls.maxPolarAngle = Math.PI * 0.49;

scene.add(new THREE.HemisphereLight(0xffffff, 0x404048, 1.3));
const sun = new THREE.DirectionalLight(0xffffff, 1.7);
sun.position.set(4, 8, 5);
scene.add(sun);

const sceneRoot = new THREE.Group();   // the scene mesh: raycast first
const overlay = new THREE.Group();     // floor, grid, bounds, route, markers: never picked
const markers = new THREE.Group();
scene.add(sceneRoot, overlay);
overlay.add(markers);
let bodyRoot = null;
let routeLine = null;
let floorPlane = new THREE.Plane(new THREE.Vector3(0, 1, 0), 0);
const NO_CUT = 1e9;
const cutPlane = new THREE.Plane(new THREE.Vector3(0, -1, 0), NO_CUT);  // keeps y <= constant

function setupStage() {
  const floorY = info.floor_y ?? 0;
  floorPlane = new THREE.Plane(new THREE.Vector3(0, 1, 0), -floorY);
  let [cx, cz, span] = [0, 0, 8];
  if (info.bounds) {
    const [[x0, z0], [x1, z1]] = info.bounds;
    [cx, cz, span] = [(x0 + x1) / 2, (z0 + z1) / 2, Math.max(x1 - x0, z1 - z0, 2)];
    const outline = new THREE.BufferGeometry().setFromPoints([
      [x0, z0], [x1, z0], [x1, z1], [x0, z1], [x0, z0],
    ].map(([x, z]) => new THREE.Vector3(x, floorY + LINE_LIFT / 2, z)));
    overlay.add(new THREE.Line(outline, new THREE.LineBasicMaterial({ color: 0x8899aa })));
  }
  if (!info.scene_url) {
    const floor = new THREE.Mesh(
      new THREE.PlaneGeometry(200, 200),
      new THREE.MeshStandardMaterial({ color: 0x8d9096, roughness: 1 }));
    floor.rotation.x = -Math.PI / 2;
    floor.position.y = floorY - 0.001;
    overlay.add(floor);
  }
  const gridSize = Math.ceil(span) + 4;
  const grid = new THREE.GridHelper(gridSize, gridSize, 0x555b66, 0x444a55);
  grid.position.set(Math.round(cx), floorY + 0.002, Math.round(cz));
  overlay.add(grid);

  camera.position.set(cx, floorY + span * 1.0, cz + span * 0.75);
  controls.target.set(cx, floorY + 0.5, cz);
  controls.update();
}

function loadGltf(url) {
  return new GLTFLoader().loadAsync(url);
}

async function loadScene() {
  if (!info.scene_url) return;
  const gltf = await loadGltf(info.scene_url);
  gltf.scene.traverse((obj) => {
    if (!obj.isMesh) return;
    for (const m of Array.isArray(obj.material) ? obj.material : [obj.material]) {
      // Scans often come without materials: glTF's default is metallic, black without an
      // environment map. Matte, both sides (open meshes, cut walls), clipped by the cut-away.
      if (m.isMeshStandardMaterial) {
        m.metalness = 0;
        m.roughness = Math.max(m.roughness, 0.6);
      }
      if (!m.map && !m.vertexColors && m.color && m.color.getHex() === 0xffffff) m.color.set(0xcfc9bf);
      m.side = THREE.DoubleSide;
      m.clippingPlanes = [cutPlane];
    }
  });
  sceneRoot.add(gltf.scene);
  // Rooms have walls: start with everything above CUT_HEIGHT cut away so the floor shows.
  const top = new THREE.Box3().setFromObject(gltf.scene).max.y;
  ui.cut.checked = top > (info.floor_y ?? 0) + 1.8;
  ui.cut.closest('.row').hidden = false;
  applyCut();
}

function applyCut() {
  cutPlane.constant = ui.cut.checked ? (info.floor_y ?? 0) + CUT_HEIGHT : NO_CUT;
}

function findBone(root, name) {
  let found = null;
  root.traverse((obj) => {
    if (!found && obj.isSkinnedMesh) found = obj.skeleton.bones.find((b) => b.name === name) || null;
  });
  return found || root.getObjectByName(name) || null;
}

async function loadBody() {
  const gltf = await loadGltf(info.body_url);
  bodyRoot = gltf.scene;
  const material = new THREE.MeshStandardMaterial({ color: 0xe8a25c, roughness: 0.65, metalness: 0 });
  bodyRoot.traverse((obj) => {
    if (obj.isMesh) {
      obj.material = material;
      obj.frustumCulled = false;   // bounds of a skinned mesh are those of its rest pose
    }
  });
  bones = info.joint_names.map((name) => findBone(bodyRoot, name));
  const missing = info.joint_names.filter((name, j) => !bones[j]);
  if (missing.length) throw new Error(`body.glb lacks bones: ${missing.join(', ')}`);
  rootBone = bones[Math.max(0, info.parents.indexOf(-1))];
  scene.add(bodyRoot);
}

function showFrame(i) {
  const q = motion.quats[i];
  const r = motion.root[i];
  for (let j = 0; j < bones.length; j++) bones[j].quaternion.set(q[j][0], q[j][1], q[j][2], q[j][3]);
  rootBone.position.set(r[0], r[1], r[2]);
  shown = i;
}

// ---------------------------------------------------------------- goals, route

function actionColor(action) {
  const k = info.actions.indexOf(action || info.default_action);
  return PALETTE[(k < 0 ? 0 : k) % PALETTE.length];
}

function labelSprite(text, color) {
  const canvas = document.createElement('canvas');
  canvas.width = 256;
  canvas.height = 64;
  const ctx = canvas.getContext('2d');
  ctx.fillStyle = 'rgba(20, 22, 28, 0.8)';
  ctx.fillRect(0, 0, canvas.width, canvas.height);
  ctx.fillStyle = `#${color.toString(16).padStart(6, '0')}`;
  ctx.font = 'bold 40px sans-serif';
  ctx.textBaseline = 'middle';
  ctx.fillText(text, 12, 34);
  const texture = new THREE.CanvasTexture(canvas);
  texture.colorSpace = THREE.SRGBColorSpace;
  const sprite = new THREE.Sprite(
    new THREE.SpriteMaterial({ map: texture, depthTest: false, sizeAttenuation: false }));
  sprite.scale.set(0.1, 0.025, 1);   // fraction of the view's height: same size at any distance
  sprite.renderOrder = 2;
  return sprite;
}

function disposeTree(obj) {
  obj.traverse((o) => {
    if (o.geometry && !o.isSprite) o.geometry.dispose();   // sprites share one geometry
    if (o.material) {
      if (o.material.map) o.material.map.dispose();
      o.material.dispose();
    }
  });
}

function updateGoals(goals) {
  const key = JSON.stringify(goals);
  if (key === goalsKey) return;
  goalsKey = key;
  for (const child of [...markers.children]) {
    markers.remove(child);
    disposeTree(child);
  }
  const floorY = info.floor_y ?? 0;
  goals.forEach((goal, k) => {
    const action = goal.action || info.default_action;
    const color = actionColor(action);
    const marker = new THREE.Group();
    const disc = new THREE.Mesh(new THREE.CylinderGeometry(0.18, 0.18, 0.02, 24),
      new THREE.MeshBasicMaterial({ color }));
    const post = new THREE.Mesh(new THREE.CylinderGeometry(0.015, 0.015, 1.4, 8),
      new THREE.MeshBasicMaterial({ color }));
    post.position.y = 0.7;
    const label = labelSprite(`${k + 1} ${action}`, color);
    label.position.y = 1.55;
    marker.add(disc, post, label);
    marker.position.set(goal.x, floorY + LINE_LIFT, goal.z);
    markers.add(marker);
  });
  ui.goals.replaceChildren(...goals.map((goal) => {
    const li = document.createElement('li');
    li.textContent = `${goal.action || info.default_action} at (${goal.x.toFixed(2)}, ${goal.z.toFixed(2)})`;
    return li;
  }));
}

function updateRoute(route) {
  const key = JSON.stringify(route || []);
  if (key === routeKey) return;
  routeKey = key;
  if (routeLine) {
    overlay.remove(routeLine);
    disposeTree(routeLine);
    routeLine = null;
  }
  if (!route || route.length < 2) return;
  const y = (info.floor_y ?? 0) + LINE_LIFT;
  const geometry = new THREE.BufferGeometry().setFromPoints(
    route.map(([x, z]) => new THREE.Vector3(x, y, z)));
  routeLine = new THREE.Line(geometry, new THREE.LineBasicMaterial({ color: 0xffee58 }));
  overlay.add(routeLine);
}

// ---------------------------------------------------------------- server sync

function showError(message, connection = false) {
  ui.error.textContent = message || '';
  errorIsConnection = connection && !!message;
}

// `sent`: when the request left. The server read its play head somewhere between then and now:
// take the middle (a busy page can see answers late; this halves that lag).
function applyState(s, seq, sent) {
  if (seq < appliedSeq) return;   // an answer overtaken by a newer one
  appliedSeq = seq;
  server = s;
  fps = s.fps || fps;
  clock = { frame: s.frame_played, at: (sent + performance.now()) / 2, playing: s.playing };
  if (!s.playing) lastLive = -1;
  updateGoals(s.goals || []);
  updateRoute(s.route);
  ui.play.textContent = s.playing && scrubFrame === null ? 'Pause' : 'Resume';
  const stall = s.stall_s > 0.05 ? ` · stall ${s.stall_s.toFixed(1)} s` : '';
  ui.status.textContent =
    `played ${s.time_played.toFixed(1)} s / generated ${s.time_generated.toFixed(1)} s${stall}\n` +
    `goals reached ${s.goals_reached} · pending ${(s.goals || []).length}\n` +
    `action: ${s.action_now}${s.playing ? '' : ' (paused)'}`;
}

async function fetchState() {
  const [seq, sent] = [++stateSeq, performance.now()];
  applyState(await request('GET', '/api/state'), seq, sent);
}

async function fetchFrames() {
  const from = motion.rev === null ? 0 : motion.root.length;
  const rev = motion.rev === null ? server.rev : motion.rev;
  const d = await request('GET', `/api/frames?from=${from}&rev=${rev}`);
  if (d.start > motion.root.length) {   // a gap: start over from frame 0 on the next poll
    motion.rev = null;
    return;
  }
  motion.root = motion.root.slice(0, d.start).concat(d.root);
  motion.quats = motion.quats.slice(0, d.start).concat(d.quats);
  motion.joints = motion.joints.slice(0, d.start).concat(d.joints);
  motion.rev = d.rev;
  if (shown >= d.start) shown = -1;      // the frame on screen changed: pose it again
  if (lastLive >= d.start) lastLive = -1;
  ui.scrub.max = String(Math.max(0, motion.root.length - 1));
}

async function poll() {
  try {
    await fetchState();
    if (server.rev !== motion.rev || server.frames_generated > motion.root.length) await fetchFrames();
    if (errorIsConnection) showError('');
  } catch (err) {
    if (err instanceof ApiError) showError(err.message);
    else showError(`server unreachable (${err.message})`, true);
  }
  setTimeout(poll, POLL_MS);
}

async function setPlaying(playing) {
  try {
    const [seq, sent] = [++stateSeq, performance.now()];
    applyState(await request('POST', '/api/play', { playing }), seq, sent);
  } catch (err) {
    showError(err.message);
  }
}

// replace: instead of the pending goals (shift-click), so the body changes course at once.
async function postGoal(x, z, replace = false) {
  const action = ui.action.value || null;
  try {
    const data = await request('POST', '/api/goals', { goals: [{ x, z, action }], replace });
    showError('');
    return { ok: true, ...data };
  } catch (err) {
    showError(err.message);
    return { ok: false, error: err.message };
  }
}

async function clearGoals() {
  try {
    await request('DELETE', '/api/goals');
    showError('');
  } catch (err) {
    showError(err.message);
  }
}

// ---------------------------------------------------------------- play head

function frameToShow(now) {
  const n = motion.root.length;
  if (n === 0) return -1;
  if (scrubFrame !== null) return Math.min(scrubFrame, n - 1);
  let f = clock.frame;
  if (clock.playing) f += Math.floor(((now - clock.at) / 1000) * fps);
  if (server) f = Math.min(f, Math.max(server.frames_generated, clock.frame + 1) - 1);
  f = Math.max(0, Math.min(f, n - 1));
  // A fresh state can land a frame or two behind the local extrapolation: don't step back.
  if (clock.playing && lastLive > f && lastLive - f <= 2 && lastLive < n) f = lastLive;
  lastLive = f;
  return f;
}

function updateScrub(f) {
  if (scrubFrame === null) ui.scrub.value = String(f);
  ui.scrubLabel.textContent = `${(Math.max(f, 0) / fps).toFixed(1)} s`;
}

// ---------------------------------------------------------------- input

const raycaster = new THREE.Raycaster();
let pressed = null;

function pickPoint(clientX, clientY) {
  const rect = renderer.domElement.getBoundingClientRect();
  const ndc = new THREE.Vector2(
    ((clientX - rect.left) / rect.width) * 2 - 1,
    -((clientY - rect.top) / rect.height) * 2 + 1);
  raycaster.setFromCamera(ndc, camera);
  const hit = raycaster.intersectObject(sceneRoot, true)
    .find((h) => h.point.y <= cutPlane.constant);   // not what is cut away
  if (hit) return hit.point;
  return raycaster.ray.intersectPlane(floorPlane, new THREE.Vector3());
}

renderer.domElement.addEventListener('pointerdown', (e) => {
  pressed = e.button === 0 ? { x: e.clientX, y: e.clientY } : null;
});
renderer.domElement.addEventListener('pointerup', (e) => {
  if (!pressed || !info) return;
  const moved = Math.hypot(e.clientX - pressed.x, e.clientY - pressed.y);
  pressed = null;
  if (moved > CLICK_SLOP_PX) return;
  const point = pickPoint(e.clientX, e.clientY);
  if (point) postGoal(point.x, point.z, e.shiftKey);
});

ui.play.addEventListener('click', () => {
  if (server && server.playing && scrubFrame === null) {
    setPlaying(false);
  } else {
    scrubFrame = null;
    setPlaying(true);
  }
});
ui.clear.addEventListener('click', clearGoals);
ui.cut.addEventListener('change', applyCut);
ui.scrub.addEventListener('input', () => {
  scrubFrame = Number(ui.scrub.value);
  ui.play.textContent = 'Resume';
  if (server && server.playing) setPlaying(false);
});

window.addEventListener('resize', () => {
  camera.aspect = window.innerWidth / window.innerHeight;
  camera.updateProjectionMatrix();
  renderer.setSize(window.innerWidth, window.innerHeight);
});

// ---------------------------------------------------------------- test hooks

const hooks = {
  ready: false,
  frameShown: -1,
  // World positions of the displayed bones, in info.joint_names order.
  boneWorldPositions() {
    bodyRoot.updateMatrixWorld(true);
    return bones.map((bone) => bone.getWorldPosition(new THREE.Vector3()).toArray());
  },
  // The click handler for the floor point (x, z): posts a goal with the dropdown's action.
  pickFloor(x, z, replace = false) {
    return postGoal(x, z, replace);
  },
  goalMarkerCount() {
    return markers.children.length;
  },
  // Page coordinates (CSS pixels) of the world point [x, y, z]: where to click to hit it.
  toScreen([x, y, z]) {
    const p = new THREE.Vector3(x, y, z).project(camera);
    const rect = renderer.domElement.getBoundingClientRect();
    return [rect.left + ((p.x + 1) / 2) * rect.width, rect.top + ((1 - p.y) / 2) * rect.height];
  },
  // What the page holds: the frames' rev and count, the frame shown and its world joints (as
  // received), and whether it follows a playing server.
  held() {
    return {
      rev: motion.rev, frames: motion.root.length, shown,
      joints: motion.joints[shown] || null, playing: clock.playing, scrubbing: scrubFrame !== null,
    };
  },
  // World positions of the bones named in info.joint_names in a .glb at `timeSeconds` of
  // animation `animationIndex` (null for a bone the file lacks).
  async loadGlbJoints(url, timeSeconds = 0, animationIndex = 0) {
    const gltf = await loadGltf(url);
    const root = gltf.scene;
    const clip = gltf.animations[animationIndex];
    if (clip) {
      const mixer = new THREE.AnimationMixer(root);
      const action = mixer.clipAction(clip);
      action.setLoop(THREE.LoopOnce, 1);
      action.clampWhenFinished = true;
      action.play();
      mixer.setTime(timeSeconds);
    } else if (animationIndex !== 0 || gltf.animations.length) {
      throw new Error(`${url} has no animation ${animationIndex}`);
    }
    root.updateMatrixWorld(true);
    return info.joint_names.map((name) => {
      const bone = findBone(root, name);
      return bone ? bone.getWorldPosition(new THREE.Vector3()).toArray() : null;
    });
  },
};
window.motiongen = hooks;

// ---------------------------------------------------------------- main

function frame() {
  requestAnimationFrame(frame);
  controls.update();
  if (bones.length) {
    const f = frameToShow(performance.now());
    if (f >= 0 && f !== shown) showFrame(f);
    if (f >= 0) {
      updateScrub(f);
      hooks.frameShown = f;
    }
  }
  renderer.render(scene, camera);
  if (!hooks.ready && shown >= 0) {
    hooks.ready = true;
    ui.loading.remove();
  }
}

async function main() {
  try {
    info = await request('GET', '/api/info');
  } catch (err) {
    ui.loading.textContent = `Cannot reach the server: ${err.message}`;
    return;
  }
  fps = info.fps || fps;
  for (const action of info.actions) ui.action.add(new Option(action, action));
  ui.action.value = info.default_action;
  setupStage();
  try {
    await Promise.all([loadScene(), loadBody()]);
  } catch (err) {
    ui.loading.textContent = `Loading failed: ${err.message}`;
    console.error(err);
    return;
  }
  for (const el of [ui.action, ui.play, ui.clear, ui.scrub]) el.disabled = false;
  poll();
  requestAnimationFrame(frame);
}

main();
