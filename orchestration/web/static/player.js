'use strict';
// player.js: a 3D skeleton player drawn by hand on a 2D canvas, and the Clock that
// keeps several players in step (compare view). Data is y-up, in metres.

const COLOURS = {
  background: '#f7f8fa',
  grid: '#e1e5ea',
  axis: '#c5ccd5',
  trail: 'rgba(84, 96, 112, 0.28)',
  trailDone: 'rgba(84, 96, 112, 0.6)',
  shadow: 'rgba(20, 30, 40, 0.09)',
  centre: '#27303b',
  left: '#1f5bd1',
  right: '#c43a2f',
};

const FOV = (40 * Math.PI) / 180;
const NEAR = 0.05; // metres; segments behind this plane are clipped, not mirrored

const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const normalize = (a) => { const n = Math.hypot(...a) || 1; return [a[0] / n, a[1] / n, a[2] / n]; };
const clamp = (x, lo, hi) => Math.min(hi, Math.max(lo, x));

/** Bounding box of every joint of every frame, and of the root's path. */
function motionBounds(joints) {
  const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
  const rootLo = [Infinity, Infinity], rootHi = [-Infinity, -Infinity];
  for (const frame of joints) {
    for (const p of frame) for (let k = 0; k < 3; k++) { lo[k] = Math.min(lo[k], p[k]); hi[k] = Math.max(hi[k], p[k]); }
    const r = frame[0];
    rootLo[0] = Math.min(rootLo[0], r[0]); rootHi[0] = Math.max(rootHi[0], r[0]);
    rootLo[1] = Math.min(rootLo[1], r[2]); rootHi[1] = Math.max(rootHi[1], r[2]);
  }
  return { lo, hi, rootLo, rootHi };
}

/** An orbiting perspective camera: target, distance, yaw (about y) and pitch. */
class Camera {
  constructor() { this.home = { target: [0, 0.9, 0], distance: 4, yaw: -0.6, pitch: 0.3 }; this.reset(); }

  reset() { Object.assign(this, structuredClone(this.home)); }

  /**
   * Frame the whole motion on a width x height canvas: look at the centre of the root's path
   * from the front-right (the figures face +z, their right is -x), slightly above, and move in
   * until the motion's bounding box fills most of the picture.
   */
  fit(bounds, width, height) {
    const { lo, hi, rootLo, rootHi } = bounds;
    const radius = 0.5 * Math.hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]);
    const target = [(rootLo[0] + rootHi[0]) / 2, (lo[1] + hi[1]) / 2, (rootLo[1] + rootHi[1]) / 2];
    // from the bounding sphere's distance every corner is in front of the camera
    this.home = { target, distance: radius / Math.sin(FOV / 2) + NEAR, yaw: -0.6, pitch: 0.3 };
    this.reset();
    const corners = [0, 1, 2, 3, 4, 5, 6, 7].map((i) => [0, 1, 2].map((k) => ((i >> k) & 1 ? hi[k] : lo[k])));
    // apparent size goes as 1 / depth, so a few rescalings settle
    for (let i = 0; i < 4; i++) {
      const view = this.view(width, height);
      const spread = Math.max(...corners.map((c) => {
        const [x, y] = view.toScreen(view.toCamera(c));
        return Math.max(Math.abs(x / width - 0.5), Math.abs(y / height - 0.5)) * 2;
      }));
      this.distance = Math.min(this.distance, Math.max(1.5, (this.distance * spread) / 0.85));
    }
    this.home.distance = this.distance;
  }

  /** The projection for a canvas of this size: world point -> camera space -> pixels. */
  view(width, height) {
    const c = Math.cos(this.pitch);
    const offset = [c * Math.sin(this.yaw), Math.sin(this.pitch), c * Math.cos(this.yaw)];
    const eye = this.target.map((t, k) => t + this.distance * offset[k]);
    const forward = normalize(sub(this.target, eye));
    const right = normalize(cross(forward, [0, 1, 0]));
    const up = cross(right, forward);
    const focal = height / 2 / Math.tan(FOV / 2);
    const toCamera = (p) => { const d = sub(p, eye); return [dot(d, right), dot(d, up), dot(d, forward)]; };
    const toScreen = (q) => [width / 2 + (focal * q[0]) / q[2], height / 2 - (focal * q[1]) / q[2]];
    return { toCamera, toScreen, focal };
  }
}

/** Add the segment a-b (world points) to the current path, clipped at the near plane. */
function clippedLine(ctx, view, a, b) {
  let p = view.toCamera(a), q = view.toCamera(b);
  if (p[2] < NEAR && q[2] < NEAR) return;
  const cut = (inside, outside) => {
    const t = (NEAR - inside[2]) / (outside[2] - inside[2]);
    return inside.map((v, k) => v + t * (outside[k] - v));
  };
  if (p[2] < NEAR) p = cut(q, p);
  else if (q[2] < NEAR) q = cut(p, q);
  const [x0, y0] = view.toScreen(p), [x1, y1] = view.toScreen(q);
  ctx.moveTo(x0, y0);
  ctx.lineTo(x1, y1);
}

/** A frame's time in seconds as the legend shows it: 0, 1.6, 2.85. */
const secondsAt = (frame, fps) => String(Number((frame / fps).toFixed(2)));

/**
 * One result on its own canvas, with a timeline of its actions and their legend under it.
 * `root` is the .player element; the player appends its canvas, timeline and legend to it. The result
 * says which joints are the body's left and right and which is the head; without them the
 * figure is drawn in one colour and without a head.
 */
class SkeletonPlayer {
  constructor(root, result, { onSeek } = {}) {
    this.root = root;
    this.joints = result.joints;
    this.parents = result.parents;
    this.actions = result.actions || [];
    this.fps = result.fps;
    this.frames = this.joints.length;
    this.duration = this.frames / this.fps;
    this.frame = 0;
    this.onSeek = onSeek || (() => {});
    this.side = this.parents.map(() => 'centre');
    (result.left_joints || []).forEach((j) => { this.side[j] = 'left'; });
    (result.right_joints || []).forEach((j) => { this.side[j] = 'right'; });
    this.head = result.head_joint ?? null;
    this.bounds = motionBounds(this.joints);
    // the head's disc is a ninth of the body's height across, as in the GIF
    const heights = this.joints[0].map((p) => p[1]);
    this.headRadius = (Math.max(...heights) - Math.min(...heights)) / 18;
    this.camera = new Camera();
    root.dataset.frames = String(this.frames);
    this.buildCanvas(Boolean(result.left_joints?.length && result.right_joints?.length));
    this.buildTimeline();
    this.buildLegend();
    this.fitted = false;
    this.resize(); // root is already in the page, so its size is known now
    this.resizer = new ResizeObserver(() => this.resize());
    this.resizer.observe(this.wrap);
  }

  /**
   * Give compared players one scale: each is fitted to its own motion, then all take the
   * farthest camera among them, so the same body is the same size in each.
   */
  static shareScale(players) {
    const distance = Math.max(...players.map((p) => p.camera.home.distance));
    players.forEach((p) => p.setHomeDistance(distance));
  }

  setHomeDistance(distance) {
    this.camera.home.distance = distance;
    this.camera.reset();
    this.draw();
  }

  buildCanvas(withSides) {
    this.wrap = document.createElement('div');
    this.wrap.className = 'canvas-wrap';
    this.canvas = document.createElement('canvas');
    this.label = document.createElement('span');
    this.label.className = 'frame-label';
    this.wrap.append(this.canvas, this.label);
    if (withSides) this.wrap.append(this.sideLegend());
    this.root.append(this.wrap);
    this.bindOrbit();
  }

  /** Which colour is the body's left and which its right, as the GIF says too. */
  sideLegend() {
    const legend = document.createElement('span');
    legend.className = 'side-legend';
    for (const side of ['left', 'right']) {
      const item = document.createElement('span');
      item.className = `side-${side}`;
      item.style.color = COLOURS[side];
      item.textContent = side;
      legend.append(item);
    }
    return legend;
  }

  /** Drag to orbit, wheel to zoom, double-click to go back to the fitted view. */
  bindOrbit() {
    let last = null;
    this.canvas.addEventListener('pointerdown', (e) => {
      last = [e.clientX, e.clientY];
      this.canvas.setPointerCapture(e.pointerId);
    });
    this.canvas.addEventListener('pointermove', (e) => {
      if (!last) return;
      const cam = this.camera;
      cam.yaw -= (e.clientX - last[0]) * 0.008;
      cam.pitch = clamp(cam.pitch + (e.clientY - last[1]) * 0.008, -0.15, 1.5);
      last = [e.clientX, e.clientY];
      this.draw();
    });
    const stop = () => { last = null; };
    this.canvas.addEventListener('pointerup', stop);
    this.canvas.addEventListener('pointercancel', stop);
    this.canvas.addEventListener('wheel', (e) => {
      e.preventDefault(); // zoom the figure, not the page
      this.camera.distance = clamp(this.camera.distance * Math.exp(e.deltaY * 0.001), 0.5, 200);
      this.draw();
    }, { passive: false });
    this.canvas.addEventListener('dblclick', () => { this.camera.reset(); this.draw(); });
  }

  buildTimeline() {
    this.timeline = document.createElement('div');
    this.timeline.className = 'timeline';
    this.segments = this.actions.map((action, i) => {
      const seg = document.createElement('div');
      seg.className = 'segment';
      seg.dataset.index = String(i);
      seg.title = `${action.text} (frames ${action.first}–${action.end - 1})`;
      seg.style.left = `${(100 * action.first) / this.frames}%`;
      seg.style.width = `${(100 * (action.end - action.first)) / this.frames}%`;
      const text = document.createElement('span');
      text.className = 'segment-label';
      seg.append(text);
      return seg;
    });
    this.playhead = document.createElement('div');
    this.playhead.className = 'playhead';
    this.timeline.append(...this.segments, this.playhead);
    this.timeline.addEventListener('pointerdown', (e) => this.seekFromTimeline(e));
    this.root.append(this.timeline);
  }

  /** Every action with its number and seconds, in full: what a short segment has no room for. */
  buildLegend() {
    this.legend = document.createElement('ol');
    this.legend.className = 'action-legend';
    this.legendItems = this.actions.map((action) => {
      const item = document.createElement('li');
      const text = document.createElement('span');
      text.className = 'legend-text';
      text.textContent = action.text;
      const time = document.createElement('span');
      time.className = 'legend-time';
      time.textContent = `${secondsAt(action.first, this.fps)}–${secondsAt(action.end, this.fps)} s`;
      item.append(text, time);
      return item;
    });
    this.legend.append(...this.legendItems);
    this.root.append(this.legend);
  }

  /** Each segment shows its action's whole text (over two lines at most), or, where that does
   *  not fit, its number in the legend: never a cut sentence. */
  fitLabels() {
    this.segments.forEach((seg, i) => {
      const label = seg.firstElementChild;
      label.textContent = this.actions[i].text;
      seg.classList.remove('numbered');
      if (label.scrollWidth > label.clientWidth || label.scrollHeight > label.clientHeight) {
        label.textContent = String(i + 1);
        seg.classList.add('numbered');
      }
    });
  }

  seekFromTimeline(e) {
    const box = this.timeline.getBoundingClientRect();
    const frame = Math.floor(clamp((e.clientX - box.left) / box.width, 0, 0.9999) * this.frames);
    this.onSeek(frame / this.fps);
  }

  /** Show the frame at `seconds` on the shared clock (held on the last frame past the end). */
  showTime(seconds) {
    this.setFrame(clamp(Math.floor(seconds * this.fps + 1e-6), 0, this.frames - 1));
  }

  setFrame(frame) {
    this.frame = frame;
    this.playhead.style.left = `${(100 * (frame + 0.5)) / this.frames}%`;
    this.actions.forEach((a, i) => {
      const active = a.first <= frame && frame < a.end;
      this.segments[i].classList.toggle('active', active);
      this.legendItems[i].classList.toggle('active', active);
    });
    this.label.textContent = `frame ${frame + 1} / ${this.frames} · ${(frame / this.fps).toFixed(2)} s`;
    this.draw();
  }

  /** Match the canvas's backing store to its CSS size times devicePixelRatio, for crisp lines. */
  resize() {
    const dpr = window.devicePixelRatio || 1;
    const w = Math.max(1, Math.round(this.wrap.clientWidth * dpr));
    const h = Math.max(1, Math.round(this.wrap.clientHeight * dpr));
    if (this.canvas.width !== w || this.canvas.height !== h) {
      this.canvas.width = w;
      this.canvas.height = h;
    }
    // fit once the real size is known; later resizes keep the user's orbit
    if (!this.fitted && w > 1 && h > 1) {
      this.camera.fit(this.bounds, w, h);
      this.fitted = true;
    }
    this.fitLabels();
    this.draw();
  }

  draw() {
    const ctx = this.canvas.getContext('2d');
    const { width, height } = this.canvas;
    const view = this.camera.view(width, height);
    const dpr = window.devicePixelRatio || 1;
    ctx.fillStyle = COLOURS.background;
    ctx.fillRect(0, 0, width, height);
    this.drawGrid(ctx, view, dpr);
    this.drawTrail(ctx, view, dpr);
    this.drawFigure(ctx, view, dpr, this.joints[this.frame]);
    this.drawHead(ctx, view);
    this.root.dataset.frame = String(this.frame);
    // CSS pixels per metre at the point the camera looks at: equal in compared players
    this.root.dataset.scale = (view.focal / this.camera.distance / dpr).toFixed(3);
  }

  /** The head's disc on the canvas, [x, y, radius] in canvas pixels, or null when there is none
   *  or it is behind the camera. */
  headOnScreen(view = this.camera.view(this.canvas.width, this.canvas.height)) {
    if (this.head === null) return null;
    const q = view.toCamera(this.joints[this.frame][this.head]);
    if (q[2] < NEAR) return null;
    return [...view.toScreen(q), (view.focal * this.headRadius) / q[2]];
  }

  /** A head on top of the figure, as the GIF draws one: the figure reads as a person at a glance. */
  drawHead(ctx, view) {
    const head = this.headOnScreen(view);
    if (!head) return;
    ctx.beginPath();
    ctx.arc(head[0], head[1], head[2], 0, 2 * Math.PI);
    ctx.fillStyle = COLOURS.centre;
    ctx.fill();
  }

  /** Half-metre grid on the floor (y = 0) around the whole motion, every metre a bit darker. */
  drawGrid(ctx, view, dpr) {
    const { lo, hi } = this.bounds;
    const step = 0.5;
    const x0 = Math.floor(lo[0] / step - 2) * step, x1 = Math.ceil(hi[0] / step + 2) * step;
    const z0 = Math.floor(lo[2] / step - 2) * step, z1 = Math.ceil(hi[2] / step + 2) * step;
    const lines = (major) => {
      ctx.beginPath();
      const isMajor = (v) => Math.abs(v - Math.round(v)) < 1e-6;
      for (let x = x0; x <= x1 + 1e-9; x += step) if (isMajor(x) === major) clippedLine(ctx, view, [x, 0, z0], [x, 0, z1]);
      for (let z = z0; z <= z1 + 1e-9; z += step) if (isMajor(z) === major) clippedLine(ctx, view, [x0, 0, z], [x1, 0, z]);
      ctx.strokeStyle = major ? COLOURS.axis : COLOURS.grid;
      ctx.lineWidth = dpr;
      ctx.stroke();
    };
    lines(false);
    lines(true);
  }

  /** The root's path on the floor: all of it faded, the part already walked stronger. */
  drawTrail(ctx, view, dpr) {
    const floor = (f) => [this.joints[f][0][0], 0, this.joints[f][0][2]];
    const path = (from, to, colour) => {
      ctx.beginPath();
      for (let f = from + 1; f <= to; f++) clippedLine(ctx, view, floor(f - 1), floor(f));
      ctx.strokeStyle = colour;
      ctx.lineWidth = 2 * dpr;
      ctx.lineCap = 'round';
      ctx.stroke();
    };
    path(0, this.frames - 1, COLOURS.trail);
    path(0, this.frame, COLOURS.trailDone);
  }

  /** Shadow on the floor, then bones (far ones first, so near ones overlap them), then joints. */
  drawFigure(ctx, view, dpr, pose) {
    const bones = [];
    this.parents.forEach((p, j) => { if (p >= 0) bones.push([p, j]); });
    const depth = (p) => view.toCamera(p)[2];
    const width = (p) => clamp((0.035 * view.focal) / Math.max(depth(p), NEAR), 1.5 * dpr, 9 * dpr);

    ctx.lineCap = 'round';
    ctx.beginPath();
    for (const [p, j] of bones) clippedLine(ctx, view, [pose[p][0], 0, pose[p][2]], [pose[j][0], 0, pose[j][2]]);
    ctx.strokeStyle = COLOURS.shadow;
    ctx.lineWidth = width(pose[0]);
    ctx.stroke();

    const mid = (p, j) => pose[p].map((v, k) => (v + pose[j][k]) / 2);
    bones.sort((a, b) => depth(mid(...b)) - depth(mid(...a)));
    for (const [p, j] of bones) {
      ctx.beginPath();
      clippedLine(ctx, view, pose[p], pose[j]);
      ctx.strokeStyle = COLOURS[this.side[j]];
      ctx.lineWidth = width(mid(p, j));
      ctx.stroke();
    }
    pose.forEach((point, j) => {
      const q = view.toCamera(point);
      if (q[2] < NEAR) return;
      const [x, y] = view.toScreen(q);
      ctx.beginPath();
      ctx.arc(x, y, width(point) * 0.75, 0, 2 * Math.PI);
      ctx.fillStyle = COLOURS[this.side[j]];
      ctx.fill();
    });
  }

  destroy() {
    this.resizer.disconnect();
  }
}

/**
 * The one clock of the page: play/pause, time in seconds, speed and loop, shared by
 * every player so compared results stay frame-aligned. The longest result sets the duration.
 */
class Clock {
  constructor() {
    this.time = 0;
    this.playing = false;
    this.speed = 1;
    this.loop = true;
    this.players = [];
    this.listeners = [];
    this.request = 0;
    this.last = null;
    this.tick = this.tick.bind(this);
  }

  get duration() {
    return this.players.reduce((longest, p) => Math.max(longest, p.duration), 0);
  }

  setPlayers(players) {
    this.pause();
    this.players.forEach((p) => p.destroy());
    this.players = players;
    this.seek(0);
  }

  /** Call `listener(clock)` after every change (the transport controls follow it). */
  onChange(listener) { this.listeners.push(listener); }

  play() {
    if (!this.players.length || this.playing) return;
    if (this.time >= this.duration) this.time = 0; // play again from the start after a stop
    this.playing = true;
    this.last = null;
    this.request = requestAnimationFrame(this.tick);
    this.render();
  }

  pause() {
    this.playing = false;
    cancelAnimationFrame(this.request);
    this.render();
  }

  toggle() { if (this.playing) this.pause(); else this.play(); }

  seek(seconds) {
    this.time = clamp(seconds, 0, this.duration);
    this.render();
  }

  tick(now) {
    if (!this.playing) return;
    // the first tick only stamps the time, so a long pause does not show up as a jump
    if (this.last !== null) this.advance(((now - this.last) / 1000) * this.speed);
    this.last = now;
    this.render();
    if (this.playing) this.request = requestAnimationFrame(this.tick);
  }

  advance(seconds) {
    const end = this.duration;
    this.time += seconds;
    if (this.time < end) return;
    if (this.loop && end > 0) this.time %= end;
    else { this.time = end; this.playing = false; }
  }

  render() {
    this.players.forEach((p) => p.showTime(this.time));
    this.listeners.forEach((listener) => listener(this));
  }
}

window.SkeletonPlayer = SkeletonPlayer;
window.Clock = Clock;
