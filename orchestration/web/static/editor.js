'use strict';
// editor.js: a result's clip edited on its timeline through POST /api/generations/{id}/edit
// (docs/serving.md): regenerate or re-time an action, lock actions, drag a boundary, pin a copied
// pose at the playhead, lay a body-part lane over a span, continue, fill the gap to another clip;
// every edit replaces the clip and can be undone.

/** A clip of the page: what it showed before each edit (undo goes back one), the actions locked
 *  against editing, and the body-part lanes laid on it (each {part, text, span: [from, to]}). */
class Clip {
  constructor(result) {
    this.history = [{ result, layers: [] }];
    this.locked = new Set();
  }

  get result() { return this.history.at(-1).result; }

  get layers() { return this.history.at(-1).layers; }

  push(result, layers) { this.history.push({ result, layers }); }

  undo() { if (this.history.length > 1) this.history.pop(); }
}

/** Seconds rounded as a field shows them. */
const roundSeconds = (seconds) => Number(seconds.toFixed(2));

/** A small labelled field of the edit panel. */
function editField(labelText, input) {
  const label = document.createElement('label');
  label.className = 'edit-field';
  label.append(labelText, input);
  return label;
}

function editInput(className, { type = 'text', placeholder = '', value = '' } = {}) {
  const input = document.createElement('input');
  Object.assign(input, { type, placeholder, value: String(value) });
  input.className = className;
  if (type === 'number') Object.assign(input, { step: 'any', min: '0.1' });
  return input;
}

function editButton(className, text, title = '') {
  const button = document.createElement('button');
  Object.assign(button, { type: 'button', className: `${className} secondary`, textContent: text, title });
  return button;
}

function editRow(title, ...children) {
  const row = document.createElement('div');
  row.className = 'edit-row';
  const heading = document.createElement('span');
  heading.className = 'edit-row-title';
  heading.textContent = title;
  row.append(heading, ...children);
  return row;
}

/**
 * The edit panel of one clip, under its player. `page` gives what the page shares: `clips()` (all
 * clips, for filling the gap to another), `send(clip, request, onProgress)` (samples an edit: the new
 * result), `show()` (draws the clips again), `time()` (the playhead, seconds), `copied` and
 * `copy(pose)` (the pose copied from a clip: {generation, frame, label}).
 */
class ClipEditor {
  constructor(root, clip, player, page) {
    Object.assign(this, { root, clip, player, page, selected: null });
    this.element = document.createElement('details');
    this.element.className = 'editor';
    this.element.open = true;
    const summary = document.createElement('summary');
    summary.textContent = 'Edit this clip';
    this.status = document.createElement('p');
    this.status.className = 'edit-status small';
    this.status.setAttribute('role', 'status');
    this.progress = document.createElement('progress');
    Object.assign(this.progress, { max: 1, value: 0, hidden: true });
    this.element.append(summary, this.actionRow(), this.poseRow(), this.layerRow(), this.continueRow());
    if (page.clips().length > 1) this.element.append(this.fillRow());
    this.element.append(this.undoRow(), this.progress, this.status);
    this.markTimeline();
    this.drawLayers();
    this.select(0);
  }

  // ---- one action: regenerate, re-time, lock ------------------------------------------

  actionRow() {
    this.actionChoice = document.createElement('select');
    this.actionChoice.className = 'edit-action';
    this.clip.result.actions.forEach((action, i) => this.actionChoice.add(new Option(`${i + 1}. ${action.text}`, i)));
    this.actionChoice.addEventListener('change', () => this.select(Number(this.actionChoice.value)));
    this.actionText = editInput('edit-text');
    this.actionSeconds = editInput('edit-seconds', { type: 'number' });
    this.lock = document.createElement('input');
    this.lock.type = 'checkbox';
    this.lock.className = 'edit-lock';
    this.lock.addEventListener('change', () => this.setLocked(this.selected, this.lock.checked));
    this.regenerate = editButton('edit-regenerate', 'Regenerate', 'Sample this action again; the others are kept');
    this.regenerate.addEventListener('click', () => this.redo(this.selected));
    const lock = document.createElement('label');
    lock.className = 'edit-field edit-lock-label';
    lock.append(this.lock, 'Lock');
    return editRow(
      'Action',
      this.actionChoice,
      editField('Text', this.actionText),
      editField('Seconds', this.actionSeconds),
      lock,
      this.regenerate,
    );
  }

  /** Action `index` chosen for the action row (a click on its segment chooses it too). */
  select(index) {
    const action = this.clip.result.actions[index];
    if (!action) return;
    this.selected = index;
    this.actionChoice.value = String(index);
    this.actionText.value = action.text;
    this.actionSeconds.value = String(roundSeconds((action.end - action.first) / this.clip.result.fps));
    this.lock.checked = this.clip.locked.has(index);
    this.regenerate.disabled = this.lock.checked;
    this.player.segments.forEach((segment, i) => segment.classList.toggle('selected', i === index));
    this.layerFrom.value = String(roundSeconds(action.first / this.clip.result.fps));
    this.layerTo.value = String(roundSeconds(action.end / this.clip.result.fps));
  }

  setLocked(index, locked) {
    if (locked) this.clip.locked.add(index);
    else this.clip.locked.delete(index);
    this.markTimeline();
    this.select(index);
  }

  /** Segments choosable by a click, locked ones marked, and a handle at each action's end that
   *  re-times it when dragged (not a locked one's). */
  markTimeline() {
    const { result } = this.clip;
    this.player.segments.forEach((segment, i) => {
      segment.classList.toggle('locked', this.clip.locked.has(i));
      segment.onclick = () => this.select(i);
    });
    this.player.timeline.querySelectorAll('.boundary').forEach((handle) => handle.remove());
    result.actions.forEach((action, i) => {
      if (this.clip.locked.has(i)) return;
      const handle = document.createElement('div');
      handle.className = 'boundary';
      handle.dataset.index = String(i);
      handle.title = `Drag to re-time “${action.text}”`;
      handle.style.left = `${(100 * action.end) / this.player.frames}%`;
      this.dragToRetime(handle, i);
      this.player.timeline.append(handle);
    });
  }

  /** Dragging action `index`'s end handle shows its new length; letting go samples it again at
   *  that length, the actions after it moved along. */
  dragToRetime(handle, index) {
    const action = this.clip.result.actions[index];
    const { fps } = this.clip.result;
    let seconds = null;
    const lengthAt = (event) => {
      const box = this.player.timeline.getBoundingClientRect();
      const end = ((event.clientX - box.left) / box.width) * this.player.duration;
      return Math.max(0.1, roundSeconds(end - action.first / fps));
    };
    handle.addEventListener('pointerdown', (event) => {
      event.stopPropagation(); // not a seek
      handle.setPointerCapture(event.pointerId);
      this.select(index);
      seconds = lengthAt(event);
    });
    handle.addEventListener('pointermove', (event) => {
      if (seconds === null) return;
      seconds = lengthAt(event);
      const box = this.player.timeline.getBoundingClientRect();
      handle.style.left = `${clamp(event.clientX - box.left, 0, box.width)}px`;
      this.actionSeconds.value = String(seconds);
    });
    handle.addEventListener('pointerup', () => {
      const length = seconds;
      seconds = null;
      if (length !== null && Math.abs(length - (action.end - action.first) / fps) >= 0.05) this.redo(index);
    });
  }

  /** Action `index` sampled again under the row's text and seconds (unchanged ones not sent). */
  redo(index) {
    const action = this.clip.result.actions[index];
    const request = { operation: 'regenerate', action: index + 1 };
    const text = this.actionText.value.trim();
    if (text && text !== action.text) request.text = text;
    const seconds = secondsOf(this.actionSeconds);
    const before = roundSeconds((action.end - action.first) / this.clip.result.fps);
    if (seconds !== null && seconds !== before) request.seconds = seconds;
    // the lanes after the action move with its end
    const shift = (seconds ?? before) - before;
    const end = action.end / this.clip.result.fps;
    const layers = this.clip.layers.map((layer) => (layer.span[0] >= end
      ? { ...layer, span: layer.span.map((s) => roundSeconds(s + shift)) } : layer));
    return this.apply(request, layers);
  }

  // ---- a pose pinned at the playhead ------------------------------------------------------

  poseRow() {
    const copy = editButton('edit-copy-pose', 'Copy pose at playhead', 'Keep this frame’s pose, to pin here or on another clip');
    copy.addEventListener('click', () => this.copyPose());
    this.pin = editButton('edit-pin', 'Pin copied pose at playhead', 'The motion passes through the copied pose here');
    this.pin.addEventListener('click', () => this.pinPose());
    this.copiedLabel = document.createElement('span');
    this.copiedLabel.className = 'edit-copied muted small';
    this.showCopied();
    return editRow('Pose', copy, this.pin, this.copiedLabel);
  }

  copyPose() {
    const { result } = this.clip;
    const seconds = this.page.time();
    // the playhead's frame as the clip was delivered (the API counts a pose's frame at its fps), the last at the end
    const frame = Math.min(Math.round(seconds * result.fps), result.joints.length - 1);
    const label = `${modelTitle(result.model, result.method)} at ${secondsText(seconds)} s`;
    this.page.copy({ generation: result.id, frame, label });
  }

  showCopied() {
    const { copied } = this.page;
    this.pin.disabled = !copied;
    this.copiedLabel.textContent = copied ? `Copied: ${copied.label}` : 'No pose copied yet.';
  }

  pinPose() {
    const { generation, frame } = this.page.copied;
    return this.apply({ operation: 'pin', pose: { generation, frame }, at: roundSeconds(this.page.time()) }, this.clip.layers);
  }

  // ---- a body-part lane over a span -----------------------------------------------------

  layerRow() {
    this.layerPart = document.createElement('select');
    this.layerPart.className = 'edit-part';
    ['upper', 'lower'].forEach((part) => this.layerPart.add(new Option(`${part} body`, part)));
    this.layerText = editInput('edit-layer-text', { placeholder: 'a person waves' });
    this.layerFrom = editInput('edit-layer-from', { type: 'number' });
    this.layerTo = editInput('edit-layer-to', { type: 'number' });
    this.layerFrom.min = '0';
    const add = editButton('edit-add-layer', 'Add lane', 'This body part does the text over the span; the rest of the body is kept');
    add.addEventListener('click', () => this.addLayer());
    return editRow(
      'Body part',
      this.layerPart,
      editField('Text', this.layerText),
      editField('From', this.layerFrom),
      editField('To', this.layerTo),
      add,
    );
  }

  addLayer() {
    const text = this.layerText.value.trim();
    if (!text) { this.say('Write what the body part does.', true); return null; }
    const span = [secondsOf(this.layerFrom), secondsOf(this.layerTo)];
    if (span.includes(null)) { this.say('Give the lane’s start and end, in seconds.', true); return null; }
    const part = this.layerPart.value;
    return this.apply({ operation: 'layer', part, text, span }, [...this.clip.layers, { part, text, span }]);
  }

  /** The body-part lanes under the timeline, overlapping ones on rows of their own. */
  drawLayers() {
    this.root.querySelector('.part-lanes')?.remove();
    if (!this.clip.layers.length) return;
    const lanes = document.createElement('div');
    lanes.className = 'part-lanes';
    const rows = [];
    for (const layer of this.clip.layers) {
      let row = rows.find((r) => r.every((other) => layer.span[0] >= other.span[1] || layer.span[1] <= other.span[0]));
      if (!row) rows.push(row = []);
      row.push(layer);
    }
    for (const row of rows) {
      const strip = document.createElement('div');
      strip.className = 'part-lane';
      for (const layer of row) {
        const box = document.createElement('div');
        box.className = 'part-layer';
        box.dataset.part = layer.part;
        box.style.left = `${(100 * layer.span[0]) / this.player.duration}%`;
        box.style.width = `${(100 * (layer.span[1] - layer.span[0])) / this.player.duration}%`;
        box.textContent = `${layer.part}: ${layer.text}`;
        box.title = `${layer.part} body, ${secondsText(layer.span[0])}–${secondsText(layer.span[1])} s: ${layer.text}`;
        strip.append(box);
      }
      lanes.append(strip);
    }
    this.player.timeline.after(lanes);
  }

  // ---- continue, fill, undo --------------------------------------------------------------

  continueRow() {
    this.nextText = editInput('edit-continue-text', { placeholder: 'a person sits down' });
    this.nextSeconds = editInput('edit-continue-seconds', { type: 'number', placeholder: 'auto' });
    const append = editButton('edit-continue', 'Append', 'A new action after the clip’s end, which is kept');
    append.addEventListener('click', () => {
      const text = this.nextText.value.trim();
      if (!text) { this.say('Write the action to append.', true); return; }
      this.apply({ operation: 'continue', actions: [{ text, seconds: secondsOf(this.nextSeconds) }] }, this.clip.layers);
    });
    return editRow('Continue', editField('Text', this.nextText), editField('Seconds', this.nextSeconds), append);
  }

  fillRow() {
    this.fillTarget = document.createElement('select');
    this.fillTarget.className = 'edit-fill-target';
    this.page.clips().forEach((other, i) => {
      if (other !== this.clip) this.fillTarget.add(new Option(`clip ${i + 1}: ${modelTitle(other.result.model, other.result.method)}`, i));
    });
    this.fillSeconds = editInput('edit-fill-seconds', { type: 'number', value: 1 });
    this.fillText = editInput('edit-fill-text', { placeholder: 'optional: what happens in the gap' });
    const fill = editButton('edit-fill', 'Fill', 'This clip, a gap sampled with both ends kept, then the other clip');
    fill.addEventListener('click', () => {
      const then = this.page.clips()[Number(this.fillTarget.value)].result.id;
      const request = { operation: 'fill', then, seconds: secondsOf(this.fillSeconds) ?? 1 };
      if (this.fillText.value.trim()) request.text = this.fillText.value.trim();
      this.apply(request, this.clip.layers);
    });
    return editRow('Fill gap to', this.fillTarget, editField('Seconds', this.fillSeconds), editField('Text', this.fillText), fill);
  }

  undoRow() {
    const undo = editButton('edit-undo', 'Undo', 'Back to this clip before its last edit');
    undo.disabled = this.clip.history.length === 1;
    undo.addEventListener('click', () => { this.clip.undo(); this.page.show(); });
    const steps = document.createElement('span');
    steps.className = 'muted small';
    steps.textContent = this.clip.history.length > 1 ? `${this.clip.history.length - 1} edit(s) made` : '';
    return editRow('', undo, steps);
  }

  // ---- sending ---------------------------------------------------------------------------

  say(message, failed = false) {
    this.status.textContent = message;
    this.status.classList.toggle('failed', failed);
  }

  /** Sample `request` on this clip; the new result (with `layers`) replaces it, undoably. */
  async apply(request, layers) {
    this.say('Sampling the edit…');
    this.progress.hidden = false;
    this.element.querySelectorAll('button').forEach((button) => { button.disabled = true; });
    try {
      const result = await this.page.send(this.clip, request, (fraction) => { this.progress.value = fraction; });
      this.clip.push(result, layers);
      this.page.show();
    } catch (err) {
      this.progress.hidden = true;
      this.say(err.message, true);
      this.element.querySelectorAll('button').forEach((button) => { button.disabled = false; });
      this.regenerate.disabled = this.clip.locked.has(this.selected);
      this.showCopied();
      this.element.querySelector('.edit-undo').disabled = this.clip.history.length === 1;
    }
  }
}

window.Clip = Clip;
window.ClipEditor = ClipEditor;
