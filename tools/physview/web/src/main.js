// physview's page: a WebSocket to the bridge (/ws), the HUD, and the draw loop. Frames are
// applied once per animation frame, the newest one only (latest wins, as in the bridge).
// window.physview exposes what was drawn, for tests and benchmarks.
import { FRAME, SHAPES, decodeFrame, decodeShapes, messageKind, messageWorld } from './protocol.js';
import { View } from './view.js';

const $ = (id) => document.getElementById(id);

const state = {
  connected: false,
  world: 0,           // selected world id
  worlds: [],         // the last "worlds" message
  tick: 0,
  time: 0,
  bodies: 0,          // bodies drawn (with shapes) in the last applied frame
  total: 0,           // bodies in the world (frame header)
  awake: 0,
  running: false,
  drawnFrames: 0,     // frames applied and drawn
  framesReceived: 0,
  framesIgnored: 0,   // frames of another world than the selected one (not drawn)
  renders: 0,         // animation frames that rendered
  animationFrames: 0, // requestAnimationFrame callbacks
  fps: 0,             // requestAnimationFrame callbacks in the last second
  appliedPerSecond: 0,// frames applied in the last second
  applyMs: 0,         // time in applying frames to the instances, total
  renderMs: 0,        // time in three.js render calls, total
  lastAck: null,
  errors: [],
};
window.physview = state;

// ?aa=0|1 (antialiasing), ?scale=R (pixel ratio): for slow machines and benchmarks; ?draw=0
// applies the frames without rendering them (a benchmark of everything but the rasterizer).
const params = new URLSearchParams(location.search);
const draw = params.get('draw') !== '0';
const view = new View($('view'), {
  antialias: params.has('aa') ? params.get('aa') !== '0' : undefined,
  pixelRatio: params.has('scale') ? Number(params.get('scale')) : undefined,
});
state.software = view.software;
state.renderer = view.rendererName;
state.antialias = view.renderer.getContextAttributes().antialias;
let pending = null;     // the newest frame not yet applied
let needRender = true;
let socket = null;

function send(msg) {
  if (socket && socket.readyState === WebSocket.OPEN) socket.send(JSON.stringify(msg));
}

function showMessage(text) {
  $('message').textContent = text;
}

function fmt(n, digits) {
  return Number.isFinite(n) ? n.toFixed(digits) : '-';
}

function updateWorlds(msg) {
  state.worlds = msg.worlds;
  if (msg.world) state.world = msg.world;
  const select = $('world');
  const wanted = msg.worlds.map((w) => `${w.id}:${w.name}`).join('|');
  if (select.dataset.worlds !== wanted) {
    select.dataset.worlds = wanted;
    select.replaceChildren(...msg.worlds.map((w) => {
      const o = document.createElement('option');
      o.value = String(w.id);
      o.textContent = `${w.name} (${w.id})`;
      return o;
    }));
  }
  select.value = String(state.world);
  const w = msg.worlds.find((x) => x.id === state.world);
  if (w) {
    state.running = w.running;
    $('state').textContent = w.running ? `running ${fmt(w.rate, 0)} Hz` : 'paused';
    $('contacts').textContent = String(w.contacts);
    $('joints').textContent = String(w.joints);
    $('tickms').textContent = fmt(w.tickMs, 2);
    state.awake = w.awake;
  }
}

function onText(text) {
  let msg;
  try {
    msg = JSON.parse(text);
  } catch {
    return;
  }
  switch (msg.type) {
    case 'hello':
      showMessage('');
      break;
    case 'worlds':
      updateWorlds(msg);
      break;
    case 'ack':
      state.lastAck = msg;
      if (msg.op === 'select') state.world = msg.world;
      if (msg.op === 'pause') { state.running = false; $('state').textContent = 'paused'; }
      if (msg.op === 'run') { state.running = true; $('state').textContent = 'running'; }
      if (msg.op === 'spawn') showMessage(`dropped a ${msg.shape} (body ${msg.id})`);
      else showMessage('');
      break;
    case 'error':
      state.errors.push(msg);
      console.warn(`physview: ${msg.op}: ${msg.code || ''} ${msg.message}`);
      showMessage(`${msg.op}: ${msg.message}`);
      break;
    default:
      break;
  }
}

function onBinary(buffer) {
  const kind = messageKind(buffer);
  if (kind === FRAME) {
    ++state.framesReceived;
    // A frame of the world the page left (sent before the select took effect) would be
    // drawn with the new world's shapes: dropped.
    if (messageWorld(buffer) !== state.world) {
      ++state.framesIgnored;
      return;
    }
    pending = buffer;  // latest wins
  } else if (kind === SHAPES) {
    const msg = decodeShapes(buffer);
    if (msg.reset) {
      // The bridge shows another world (or none: 0) from here on: nothing of the old one stays.
      state.world = msg.world;
      pending = null;
      view.clear();
      state.bodies = 0;
    } else if (msg.world !== state.world) {
      return;
    }
    view.addShapes(msg);
    needRender = true;
  }
}

function connect() {
  const url = `${location.protocol === 'https:' ? 'wss' : 'ws'}://${location.host}/ws`;
  const ws = new WebSocket(url);
  ws.binaryType = 'arraybuffer';
  ws.onopen = () => {
    state.connected = true;
    $('state').textContent = 'connected';
  };
  ws.onmessage = (ev) => {
    if (typeof ev.data === 'string') onText(ev.data);
    else onBinary(ev.data);
  };
  ws.onclose = () => {
    state.connected = false;
    $('state').textContent = 'disconnected: retrying';
    socket = null;
    setTimeout(connect, 1000);
  };
  socket = ws;
}

// HUD controls.
$('world').addEventListener('change', (ev) => send({ op: 'select', world: Number(ev.target.value) }));
$('run').addEventListener('click', () => send({ op: 'run', rate: 60 }));
$('pause').addEventListener('click', () => send({ op: 'pause' }));
$('step').addEventListener('click', () => send({ op: 'step', n: 1 }));

// A click (not a drag) on the view drops a body there.
const canvas = view.renderer.domElement;
let down = null;
canvas.addEventListener('pointerdown', (ev) => {
  down = ev.button === 0 ? { x: ev.clientX, y: ev.clientY } : null;
});
canvas.addEventListener('pointerup', (ev) => {
  if (!down || ev.button !== 0) return;
  const moved = Math.hypot(ev.clientX - down.x, ev.clientY - down.y);
  down = null;
  if (moved > 5) return;
  const at = view.pick(ev.clientX, ev.clientY);
  if (!at) return;
  const shape = $('spawn-ball').checked ? 'ball' : 'box';
  send({ op: 'spawn', shape, at });
});
view.controls.addEventListener('change', () => { needRender = true; });
window.addEventListener('resize', () => { view.resize(); needRender = true; });

// The draw loop, with one-second rates.
let second = performance.now();
let rafInSecond = 0;
let appliedInSecond = 0;
function loop(now) {
  requestAnimationFrame(loop);
  ++state.animationFrames;
  ++rafInSecond;
  let applied = false;
  if (pending) {
    const t0 = performance.now();
    const frame = decodeFrame(pending);
    pending = null;
    view.apply(frame);
    state.applyMs += performance.now() - t0;
    applied = true;
    ++appliedInSecond;
    state.tick = frame.tick;
    state.time = frame.time;
    state.total = frame.total;
    state.bodies = view.drawnBodies;
    state.running = frame.running;
    $('tick').textContent = String(frame.tick);
    $('time').textContent = `${fmt(frame.time, 2)} s`;
    $('tickms').textContent = fmt(frame.tickMs, 2);
    $('bodies').textContent = `${frame.awake} / ${frame.total}`;
  }
  if (draw && (applied || needRender)) {
    const t0 = performance.now();
    view.render();
    state.renderMs += performance.now() - t0;
    ++state.renders;
    needRender = false;
  }
  if (applied) ++state.drawnFrames;
  if (now - second >= 1000) {
    const s = (now - second) / 1000;
    state.fps = rafInSecond / s;
    state.appliedPerSecond = appliedInSecond / s;
    $('fps').textContent = `${fmt(state.appliedPerSecond, 0)} (display ${fmt(state.fps, 0)} Hz)`;
    second = now;
    rafInSecond = 0;
    appliedInSecond = 0;
  }
}

connect();
requestAnimationFrame(loop);
// A quiet page keeps its WebSocket alive.
setInterval(() => send({ op: 'ping' }), 5000);
