'use strict';
// app.js: the form, the calls to the API, progress, results, compare view, downloads.

const $ = (selector, root = document) => root.querySelector(selector);
const $$ = (selector, root = document) => [...root.querySelectorAll(selector)];

const state = { token: null, catalog: null, clock: new Clock() };
window.m2d2m = state; // for poking at from the browser console

// ---- token and API --------------------------------------------------------------

/** Take ?token= from the address (then hide it there), else the one kept for this tab. */
function readToken() {
  const url = new URL(window.location.href);
  const fromUrl = url.searchParams.get('token');
  if (fromUrl) {
    sessionStorage.setItem('m2d2m-token', fromUrl);
    url.searchParams.delete('token');
    history.replaceState(null, '', url.pathname + url.search + url.hash);
  }
  state.token = fromUrl || sessionStorage.getItem('m2d2m-token');
}

/** fetch() with the token; any non-2xx answer becomes an Error carrying the server's sentence. */
async function api(path, options = {}) {
  const headers = new Headers(options.headers || {});
  if (state.token) headers.set('Authorization', `Bearer ${state.token}`);
  let response;
  try {
    response = await fetch(path, { ...options, headers });
  } catch (err) {
    throw new Error('The server could not be reached.');
  }
  if (response.status === 401) $('#token-box').hidden = false;
  if (!response.ok) throw new Error(await errorSentence(response));
  return response;
}

async function errorSentence(response) {
  try {
    const body = await response.json();
    if (body && typeof body.error === 'string') return body.error;
  } catch (err) { /* not JSON: fall through to the status line */ }
  return `The server answered ${response.status} ${response.statusText}.`.replace(' .', '.');
}

function showError(message) {
  const box = $('#error');
  box.textContent = message;
  box.hidden = !message;
}

function withToken(href) {
  if (!state.token) return href;
  return `${href}${href.includes('?') ? '&' : '?'}token=${encodeURIComponent(state.token)}`;
}

// ---- actions ----------------------------------------------------------------------

function addAction(text = '', seconds = null) {
  const row = $('#action-template').content.firstElementChild.cloneNode(true);
  $('.action-text', row).value = text;
  $('.action-seconds', row).value = seconds === null ? '' : String(seconds);
  if (state.catalog?.max_seconds) $('.action-seconds', row).max = state.catalog.max_seconds;
  $('#actions').append(row);
  return row;
}

/** Up, down and remove buttons of every row, through one listener on the list. */
function onActionButton(event) {
  const button = event.target.closest('button');
  const row = button && button.closest('.action');
  if (!row) return;
  if (button.classList.contains('action-up') && row.previousElementSibling) row.previousElementSibling.before(row);
  if (button.classList.contains('action-down') && row.nextElementSibling) row.nextElementSibling.after(row);
  if (button.classList.contains('action-remove')) row.remove();
}

function mode() {
  return $('input[name="mode"]:checked').value;
}

function showMode() {
  $('#list-mode').hidden = mode() !== 'list';
  $('#sentence-mode').hidden = mode() !== 'sentence';
}

/** An empty seconds input means "the model's typical length": null. */
function secondsOf(input) {
  return input.value.trim() === '' ? null : Number(input.value);
}

/** The part of the request every lane shares: the actions (or the sentence) and the seed. */
function sharedRequest() {
  const body = { seed: Number($('#seed').value || 0) };
  if (mode() === 'sentence') {
    body.prompt = $('#prompt').value.trim();
    if (!body.prompt) throw new Error('Write a sentence describing the motion.');
    const seconds = secondsOf($('#prompt-seconds'));
    if (seconds !== null) body.seconds = seconds;
    return body;
  }
  body.actions = $$('#actions .action').map((row) => ({
    text: $('.action-text', row).value.trim(),
    seconds: secondsOf($('.action-seconds', row)),
  }));
  if (!body.actions.length) throw new Error('Add at least one action.');
  const empty = body.actions.findIndex((a) => !a.text);
  if (empty >= 0) throw new Error(`Action ${empty + 1} has no text.`);
  return body;
}

// ---- knobs: built from the model's list, nothing model-specific here ------------------

function knobInput(knob) {
  let input;
  if (knob.kind === 'str' && knob.choices) {
    input = document.createElement('select');
    const choices = knob.optional ? ['', ...knob.choices] : knob.choices;
    for (const choice of choices) input.add(new Option(choice === '' ? '(model decides)' : choice, choice));
  } else {
    input = document.createElement('input');
    if (knob.kind === 'str') input.type = 'text';
    else {
      input.type = 'number';
      input.step = knob.kind === 'int' ? '1' : 'any';
      // "above" is an exclusive bound, which HTML cannot say: the server checks it
      const low = knob.minimum ?? knob.above;
      if (low !== null && low !== undefined) input.min = String(low);
      if (knob.maximum !== null && knob.maximum !== undefined) input.max = String(knob.maximum);
    }
    if (knob.optional) input.placeholder = 'model decides';
  }
  input.value = knob.default === null || knob.default === undefined ? '' : String(knob.default);
  input.dataset.knob = knob.name;
  input.title = knob.help || knob.name;
  return input;
}

function knobRow(knob) {
  const label = document.createElement('label');
  label.className = 'knob';
  label.title = knob.help || '';
  const name = document.createElement('span');
  name.textContent = knob.name;
  label.append(name, knobInput(knob));
  return label;
}

/** The knob's value when the user changed it from its default, else undefined (not sent). */
function knobValue(input, knob) {
  const raw = input.value.trim();
  if (raw === '') return undefined; // empty: let the model decide
  const value = knob.kind === 'str' ? raw : Number(raw);
  return value === knob.default ? undefined : value;
}

// ---- lanes: one model / run / method / knobs each ------------------------------------

const modelNamed = (name) => state.catalog.models.find((m) => m.name === name);

function setOptions(select, pairs, chosen) {
  select.replaceChildren(...pairs.map(([value, label]) => new Option(label, value)));
  if (chosen !== undefined && pairs.some(([value]) => value === chosen)) select.value = chosen;
}

function addLane(modelName, runId, method) {
  const lane = $('#lane-template').content.firstElementChild.cloneNode(true);
  const models = state.catalog.models;
  setOptions($('.lane-model', lane), models.map((m) => [m.name, m.name]));
  $('.lane-model', lane).addEventListener('change', (e) => fillLane(lane, e.target.value));
  $('.lane-run', lane).addEventListener('change', () => loadRunKnobs(lane));
  $('.lane-remove', lane).addEventListener('click', () => { lane.remove(); numberLanes(); });
  $('#lanes').append(lane);
  fillLane(lane, modelName || models[0].name, runId, method);
  numberLanes();
  return lane;
}

/** (Re)build a lane's run, method and knob controls for `modelName`. */
function fillLane(lane, modelName, runId, method) {
  const model = modelNamed(modelName);
  $('.lane-model', lane).value = model.name;
  $('.lane-summary', lane).textContent = model.summary || '';
  const latest = model.runs.find((r) => r.latest) || model.runs[0];
  setOptions($('.lane-run', lane), model.runs.map((r) => [r.id, r.label || r.id]), runId || latest.id);
  const methods = model.methods || [];
  setOptions($('.lane-method', lane), methods.map((m) => [m, m]), method || model.default_method);
  $('.lane-method-label', lane).hidden = methods.length === 0;
  showKnobs(lane, model.knobs || []);
  loadRunKnobs(lane);
}

function showKnobs(lane, knobs) {
  lane.knobs = knobs;
  $('.lane-knobs', lane).replaceChildren(...knobs.map(knobRow));
}

/** A model file may carry its own sampling defaults (the steps it was tuned for): ask the server
 *  for the run's, which loads the model once so that the first Generate is quick too. */
async function loadRunKnobs(lane) {
  const model = $('.lane-model', lane).value;
  const run = $('.lane-run', lane).value;
  try {
    const path = `/api/models/${encodeURIComponent(model)}/runs/${encodeURIComponent(run)}`;
    const details = await (await api(path)).json();
    const unchanged = $('.lane-model', lane).value === model && $('.lane-run', lane).value === run;
    if (unchanged) showKnobs(lane, details.knobs);
  } catch (err) {
    showError(err.message);
  }
}

function numberLanes() {
  const lanes = $$('#lanes .lane');
  lanes.forEach((lane, i) => {
    $('.lane-name', lane).textContent = `Lane ${i + 1}`;
    $('.lane-head', lane).hidden = lanes.length === 1; // its name and remove button
    $('.lane-remove', lane).hidden = lanes.length === 1;
  });
}

/** Compare: a new lane with the last lane's model and run, and the next method of that model. */
function addCompareLane() {
  const last = $$('#lanes .lane').pop();
  const model = modelNamed($('.lane-model', last).value);
  const methods = model.methods || [];
  const next = methods[(methods.indexOf($('.lane-method', last).value) + 1) % Math.max(methods.length, 1)];
  addLane(model.name, $('.lane-run', last).value, next);
}

function laneRequest(lane) {
  const model = modelNamed($('.lane-model', lane).value);
  const body = { model: model.name, run: $('.lane-run', lane).value, options: {} };
  if ((model.methods || []).length) body.method = $('.lane-method', lane).value;
  for (const knob of lane.knobs || []) {
    const value = knobValue($(`[data-knob="${CSS.escape(knob.name)}"]`, lane), knob);
    if (value !== undefined) body.options[knob.name] = value;
  }
  return body;
}

function laneTitle(lane) {
  const method = $('.lane-method-label', lane).hidden ? '' : ` · ${$('.lane-method', lane).value}`;
  return `${$('.lane-model', lane).value}${method}`;
}

// ---- generate: one streamed request per lane, all at once -----------------------------

/** Call `onMessage` with each JSON line of a streamed (NDJSON) answer. */
async function readLines(response, onMessage) {
  const reader = response.body.getReader();
  const decoder = new TextDecoder();
  let buffer = '';
  for (;;) {
    const { value, done } = await reader.read();
    buffer += decoder.decode(value || new Uint8Array(), { stream: !done });
    const lines = buffer.split('\n');
    buffer = done ? '' : lines.pop(); // keep a partial last line for the next chunk
    for (const line of lines) if (line.trim()) onMessage(JSON.parse(line));
    if (done) return;
  }
}

function setLaneProgress(lane, fraction, status) {
  $('.lane-state', lane).hidden = false;
  $('.lane-progress', lane).value = fraction;
  $('.lane-status', lane).textContent = status;
  const all = $$('#lanes .lane-progress').map((p) => p.value);
  $('#progress').value = all.reduce((a, b) => a + b, 0) / all.length;
}

async function runLane(lane, body) {
  setLaneProgress(lane, 0, 'starting…');
  const response = await api('/api/generate', {
    method: 'POST',
    headers: { 'Content-Type': 'application/json', Accept: 'application/x-ndjson' },
    body: JSON.stringify(body),
  });
  let result = null;
  await readLines(response, (message) => {
    if (message.error) throw new Error(message.error);
    if (message.result) result = message.result;
    else if ('queued' in message) setLaneProgress(lane, 0, `queued: position ${message.queued}`);
    else if ('progress' in message) setLaneProgress(lane, message.progress, `${Math.round(message.progress * 100)} %`);
  });
  if (!result) throw new Error('The server ended its answer without a result.');
  setLaneProgress(lane, 1, 'done');
  return result;
}

/** Check the visible inputs against their HTML limits (min, max, step) before sending. */
function formIsValid() {
  const shown = $$('#form input, #form select, #form textarea').filter((el) => el.offsetParent !== null);
  const bad = shown.find((el) => !el.checkValidity());
  if (!bad) return true;
  bad.reportValidity();
  const name = bad.dataset.knob || bad.getAttribute('aria-label') || bad.id || 'A field';
  showError(`${name}: ${bad.validationMessage}`);
  return false;
}

async function generate() {
  showError('');
  if (!state.catalog || !formIsValid()) return;
  let shared;
  try {
    shared = sharedRequest();
  } catch (err) {
    showError(err.message);
    return;
  }
  const lanes = $$('#lanes .lane');
  const button = $('#generate');
  button.disabled = true;
  $('#progress').hidden = false;
  $('#progress').value = 0;
  state.clock.pause();
  const outcomes = await Promise.allSettled(lanes.map((lane) => runLane(lane, { ...shared, ...laneRequest(lane) })));
  button.disabled = false;
  $('#progress').hidden = true;
  reportOutcomes(lanes, outcomes);
}

function reportOutcomes(lanes, outcomes) {
  const failed = outcomes.map((o, i) => [o, lanes[i]]).filter(([o]) => o.status === 'rejected');
  failed.forEach(([, lane]) => setLaneProgress(lane, 0, 'failed'));
  const prefix = (lane) => (lanes.length > 1 ? `${laneTitle(lane)}: ` : '');
  showError(failed.map(([o, lane]) => prefix(lane) + o.reason.message).join(' '));
  const results = outcomes.filter((o) => o.status === 'fulfilled').map((o) => o.value);
  if (results.length) showResults(results);
}

// ---- results ----------------------------------------------------------------------------

function downloadLinks(files) {
  const box = document.createElement('div');
  box.className = 'downloads';
  for (const [format, href] of Object.entries(files || {})) {
    const link = document.createElement('a');
    link.href = withToken(href);
    link.download = '';
    link.dataset.format = format;
    link.textContent = format.toUpperCase();
    box.append(link);
  }
  return box;
}

function mlflowLine(mlflow) {
  const line = document.createElement('div');
  line.className = 'mlflow';
  if (!mlflow || !mlflow.run_id) return line;
  line.append(`MLflow run${mlflow.experiment ? ` (${mlflow.experiment})` : ''}: `);
  const id = document.createElement(mlflow.url ? 'a' : 'code');
  id.textContent = mlflow.run_id;
  if (mlflow.url) Object.assign(id, { href: mlflow.url, target: '_blank', rel: 'noopener' });
  line.append(id);
  return line;
}

function playerElement(result) {
  const article = document.createElement('article');
  article.className = 'player';
  const title = document.createElement('h3');
  title.className = 'player-title';
  title.textContent = [result.model, result.method, result.describe].filter(Boolean).join(' · ');
  title.title = title.textContent; // the full title when the heading is cut short
  const meta = document.createElement('p');
  meta.className = 'player-meta muted small';
  meta.textContent = `run ${result.run} · seed ${result.seed} · ${Number(result.seconds).toFixed(1)} s at ${result.fps} fps`;
  article.append(title, meta);
  return article;
}

function showResults(results) {
  const area = $('#players');
  area.replaceChildren();
  const seek = (seconds) => { state.clock.pause(); state.clock.seek(seconds); };
  const players = results.map((result) => {
    const article = playerElement(result);
    area.append(article);
    const player = new SkeletonPlayer(article, result, { onSeek: seek });
    article.append(downloadLinks(result.files), mlflowLine(result.mlflow));
    return player;
  });
  area.classList.toggle('many', players.length > 1);
  state.clock.setPlayers(players);
  state.clock.play();
}

// ---- transport: one for all players ---------------------------------------------------

function bindTransport() {
  const clock = state.clock;
  $('#play').addEventListener('click', () => clock.toggle());
  $('#scrub').addEventListener('input', (e) => {
    const seconds = Number(e.target.value); // read first: pausing re-renders the scrub
    clock.pause();
    clock.seek(seconds);
  });
  $('#speed').addEventListener('change', (e) => { clock.speed = Number(e.target.value); });
  $('#loop').addEventListener('change', (e) => { clock.loop = e.target.checked; });
  clock.speed = Number($('#speed').value);
  clock.loop = $('#loop').checked;
  clock.onChange(showClock);
}

function showClock(clock) {
  const none = clock.players.length === 0;
  $('#play').textContent = clock.playing ? 'Pause' : 'Play';
  $('#play').disabled = none;
  const scrub = $('#scrub');
  scrub.disabled = none;
  scrub.max = String(clock.duration);
  scrub.value = String(clock.time);
  $('#time').textContent = `${clock.time.toFixed(2)} / ${clock.duration.toFixed(2)} s`;
}

// ---- start ----------------------------------------------------------------------------

async function loadModels() {
  showError('');
  try {
    state.catalog = await (await api('/api/models')).json();
  } catch (err) {
    showError(err.message);
    return;
  }
  const { dataset, max_seconds: max, models } = state.catalog;
  $('#dataset').textContent = `dataset: ${dataset} · ${max ? `up to ${max} s` : 'no length cap'}`;
  if (max) $$('.action-seconds, #prompt-seconds').forEach((input) => { input.max = max; });
  $('#lanes').replaceChildren();
  if (!models.length) {
    showError('No trained model yet: train one, then reload this page.');
    return;
  }
  addLane();
  $('#generate').disabled = false;
  $('#compare').disabled = false;
}

function retryWithToken() {
  state.token = $('#token').value.trim() || null;
  if (state.token) sessionStorage.setItem('m2d2m-token', state.token);
  $('#token-box').hidden = true;
  if (state.catalog) generate();
  else loadModels();
}

function start() {
  readToken();
  addAction('a person walks forward', 3);
  addAction('a person jumps', 2);
  $('#actions').addEventListener('click', onActionButton);
  $('#add-action').addEventListener('click', () => $('.action-text', addAction()).focus());
  $$('input[name="mode"]').forEach((radio) => radio.addEventListener('change', showMode));
  $('#compare').addEventListener('click', addCompareLane);
  $('#form').addEventListener('submit', (e) => { e.preventDefault(); generate(); });
  $('#token-retry').addEventListener('click', retryWithToken);
  bindTransport();
  showMode();
  loadModels();
}

start();
