'use strict';
// app.js: the form, the calls to the API, progress, results, compare view, downloads.

const $ = (selector, root = document) => root.querySelector(selector);
const $$ = (selector, root = document) => [...root.querySelectorAll(selector)];

const state = {
  token: null, catalog: null, clock: new Clock(), rig: null, rigFile: null, clips: [], editors: [],
};
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
  if (!response.ok) throw Object.assign(new Error(await errorSentence(response)), { status: response.status });
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

/** `href` with `key=value` added to its query (after a ? or an &, as it already has one). */
function withQuery(href, key, value) {
  return `${href}${href.includes('?') ? '&' : '?'}${key}=${encodeURIComponent(value)}`;
}

function withToken(href) {
  return state.token ? withQuery(href, 'token', state.token) : href;
}

// ---- actions ----------------------------------------------------------------------

function addAction(text = '', seconds = null) {
  const row = $('#action-template').content.firstElementChild.cloneNode(true);
  const field = $('.action-text', row);
  field.value = text;
  field.addEventListener('input', () => onActionInput(field));
  field.addEventListener('keydown', onActionKey);
  $('.action-seconds', row).value = seconds === null ? '' : String(seconds);
  $('#actions').append(row);
  limitSeconds($('.action-seconds', row), actionRange());
  fitHeight(field);
  return row;
}

/** An action is one line of text (a line break is a control character the server refuses),
 *  shown whole: the field grows with its sentence. */
function onActionInput(field) {
  if (/[\r\n]/.test(field.value)) field.value = field.value.replace(/\s*[\r\n]+\s*/g, ' ');
  fitHeight(field);
}

/** Enter generates, as in a one-line field. */
function onActionKey(event) {
  if (event.key !== 'Enter' || event.shiftKey || event.isComposing) return;
  event.preventDefault();
  $('#form').requestSubmit();
}

/** Grow a textarea to its text's height, so no part of its sentence is out of sight. */
function fitHeight(field) {
  if (field.offsetParent === null) return; // not laid out: fitted when shown
  field.style.height = 'auto';
  field.style.height = `${field.scrollHeight + field.offsetHeight - field.clientHeight}px`;
}

/** Put an example sentence in the last empty action, or in a new one; in one-sentence mode, at
 *  the end of the sentence. */
function useExample(example) {
  if (mode() === 'sentence') {
    const prompt = $('#prompt');
    prompt.value = prompt.value.trim() ? `${prompt.value.trim()} and then ${example}` : example;
    prompt.focus();
    return;
  }
  const empty = $$('#actions .action-text').filter((field) => !field.value.trim()).pop();
  const field = empty || $('.action-text', addAction());
  field.value = example;
  fitHeight(field);
  field.focus();
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
  $$('#actions .action-text').forEach(fitHeight);
}

/** The sentence split into actions by the first lane's run, as generating it would split it,
 *  put in the list (the sentence's seconds shared among them) to be checked and fixed there. */
async function splitPrompt() {
  showError('');
  const prompt = $('#prompt').value.trim();
  if (!prompt) { showError('Write a sentence describing the motion.'); return; }
  const lane = $('#lanes .lane');
  if (!lane) { showError('No trained model yet: train one, then reload this page.'); return; }
  const { model, run } = laneRequest(lane);
  let split;
  try {
    const request = { method: 'POST', headers: { 'Content-Type': 'application/json' } };
    split = await (await api('/api/split', { ...request, body: JSON.stringify({ model, run, prompt }) })).json();
  } catch (err) {
    showError(err.message);
    return;
  }
  const total = secondsOf($('#prompt-seconds'));
  const each = total === null ? null : Number((total / split.actions.length).toFixed(2));
  $('#actions').replaceChildren();
  split.actions.forEach((action) => addAction(action, each));
  $('input[name="mode"][value="list"]').checked = true;
  showMode();
  showNotices([split]);
}

/** An empty seconds input means "the model's typical length": null. */
function secondsOf(input) {
  return input.value.trim() === '' ? null : Number(input.value);
}

/** How the files are delivered, as `m2d2m generate`'s options: the same for every lane. */
function deliveryRequest() {
  return {
    fps: $('#fps').value ? Number($('#fps').value) : null, // null: the model's own rate
    root: $('#root').value,
    loop: $('#delivery-loop').checked,
    plant_feet: $('#plant-feet').checked,
  };
}

/** The part of the request every lane shares: the actions (or the sentence), the first seed and
 *  the delivery. */
function sharedRequest() {
  const body = { seed: Number($('#seed').value || 0), ...deliveryRequest() };
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
      // "above" is an exclusive bound, which HTML cannot say: the hint says it, the server checks it
      const low = knob.minimum ?? knob.above;
      if (low !== null && low !== undefined) input.min = String(low);
      if (knob.maximum !== null && knob.maximum !== undefined) input.max = String(knob.maximum);
    }
    if (knob.optional) input.placeholder = 'model decides';
  }
  input.value = knob.default === null || knob.default === undefined ? '' : String(knob.default);
  input.dataset.knob = knob.name;
  input.dataset.label = knob.label || knob.name;
  return input;
}

const given = (value) => value !== null && value !== undefined;

/** The values a number knob takes, in words: "whole number, at least 1", "above 0, at most 1". */
function rangeHint(knob) {
  if (knob.kind === 'str') return '';
  const bounds = [];
  if (given(knob.minimum)) bounds.push(`at least ${knob.minimum}`);
  if (given(knob.above)) bounds.push(`above ${knob.above}`);
  if (given(knob.maximum)) bounds.push(`at most ${knob.maximum}`);
  if (given(knob.minimum) && given(knob.maximum)) bounds.splice(0, 2, `${knob.minimum} to ${knob.maximum}`);
  const words = [knob.kind === 'int' ? 'whole number' : 'number', ...bounds].join(', ');
  return knob.optional ? `${words}; empty: the model decides` : words;
}

/** Help as the page shows it, a sentence: a declaration's starts lower-case, as on the command line. */
const asSentence = (text) => (text ? `${text[0].toUpperCase()}${text.slice(1)}${/[.!?]$/.test(text) ? '' : '.'}` : '');

/** A knob for people: its label, its own name as a small hint, the field with its limits beside
 *  it, and its help in view under it. */
function knobRow(knob) {
  const row = document.createElement('label');
  row.className = 'knob';
  row.dataset.knobRow = knob.name;
  const title = document.createElement('span');
  title.className = 'knob-title';
  const label = document.createElement('span');
  label.className = 'knob-label';
  label.textContent = knob.label || knob.name;
  const name = document.createElement('code');
  name.className = 'knob-name';
  name.textContent = knob.name;
  title.append(label, name);
  const field = document.createElement('span');
  field.className = 'knob-field';
  const range = document.createElement('span');
  range.className = 'knob-range';
  range.textContent = rangeHint(knob);
  field.append(knobInput(knob), range);
  const help = document.createElement('span');
  help.className = 'knob-help';
  help.textContent = asSentence(knob.help);
  row.append(title, field, help);
  return row;
}

/** Whether a knob matters for `method` (a knob that names none matters for every method). */
const knobApplies = (knob, method) => !knob.methods || knob.methods.includes(method);

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
  $('.lane-method', lane).addEventListener('change', () => showMethodKnobs(lane));
  $('.lane-remove', lane).addEventListener('click', () => { lane.remove(); numberLanes(); showRunFacts(); });
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
  const labels = model.method_labels || {};
  setOptions($('.lane-method', lane), methods.map((m) => [m, labels[m] || m]), method || model.default_method);
  $('.lane-method-label', lane).hidden = methods.length === 0;
  lane.details = null; // the run's facts, until the server has told them
  showRunFacts();
  showKnobs(lane, model.knobs || []);
  loadRunKnobs(lane);
}

function showKnobs(lane, knobs) {
  lane.knobs = knobs;
  $('.lane-knobs', lane).replaceChildren(...knobs.map(knobRow));
  showMethodKnobs(lane);
}

/** Show only the knobs that matter for the lane's method; the hidden ones are not sent. */
function showMethodKnobs(lane) {
  const method = laneMethod(lane);
  for (const knob of lane.knobs || []) {
    $(`[data-knob-row="${CSS.escape(knob.name)}"]`, lane).hidden = !knobApplies(knob, method);
  }
}

/** The lane's method, or null for a model with none. */
function laneMethod(lane) {
  return $('.lane-method-label', lane).hidden ? null : $('.lane-method', lane).value;
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
    if (!unchanged) return;
    lane.details = details;
    showKnobs(lane, details.knobs);
    showRunFacts();
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
  const body = { model: $('.lane-model', lane).value, run: $('.lane-run', lane).value, options: {} };
  const method = laneMethod(lane);
  if (method !== null) body.method = method;
  for (const knob of (lane.knobs || []).filter((k) => knobApplies(k, method))) {
    const value = knobValue($(`[data-knob="${CSS.escape(knob.name)}"]`, lane), knob);
    if (value !== undefined) body.options[knob.name] = value;
  }
  return body;
}

/** "model · method", the method by its label. */
function modelTitle(modelName, method) {
  const labels = modelNamed(modelName)?.method_labels || {};
  return [modelName, method && (labels[method] || method)].filter(Boolean).join(' · ');
}

function laneTitle(lane) {
  return modelTitle($('.lane-model', lane).value, laneMethod(lane));
}

// ---- what the lanes' runs accept and know: the action lengths, the actions -------------

/** Seconds as people write them: 0.2, 4.8, 60. */
const secondsText = (seconds) => String(Number(seconds.toFixed(2)));

/** The seconds one action may last in every lane's run and under the server's cap:
 *  [shortest, longest], or null until the runs are known. */
function actionRange() {
  const ranges = $$('#lanes .lane').map((lane) => lane.details?.seconds).filter(Boolean);
  if (!ranges.length) return null;
  const longest = Math.min(...ranges.map((r) => r[1]), state.catalog?.max_seconds || Infinity);
  return [Math.max(...ranges.map((r) => r[0])), longest];
}

/** An action's seconds field takes what the runs accept; "any" step, as the shortest need not be
 *  a multiple of 0.1 and HTML counts steps from the minimum. */
function limitSeconds(input, range) {
  input.step = 'any';
  if (range) Object.assign(input, { min: String(range[0]), max: String(range[1]) });
  input.title = range ? `${secondsText(range[0])}–${secondsText(range[1])} s; empty: the model's typical length` : '';
}

/** The header's and the fields' limits, and the actions the runs know: after any lane changes. */
function showRunFacts() {
  if (!state.catalog) return;
  const range = actionRange();
  const max = state.catalog.max_seconds;
  const span = range && `${secondsText(range[0])}–${secondsText(range[1])}`;
  const total = max ? `up to ${secondsText(max)} s in all` : 'no cap on the total';
  $('#dataset').textContent = `dataset: ${state.catalog.dataset} · ${total}${range ? `, each action ${span} s` : ''}`;
  $$('#actions .action-seconds').forEach((input) => limitSeconds(input, range));
  const whole = $('#prompt-seconds');
  if (range) whole.min = String(range[0]);
  if (max) whole.max = String(max);
  const cap = max ? `; at most ${secondsText(max)} s in all` : '';
  $('#seconds-hint').textContent = range
    ? `Seconds: ${span} for each action; empty: the model's typical length${cap}.`
    : "Empty seconds: the model's typical length for that action.";
  $('#prompt-seconds-hint').textContent = range ? `Each action ${span} s${cap}; empty: typical lengths.` : '';
  showModelRate();
  showKnownActions();
}

/** The frame-rate menu's first choice says the runs' own rate: "The model's (20 fps)". */
function showModelRate() {
  const rates = [...new Set($$('#lanes .lane').map((lane) => lane.details?.fps).filter(Boolean))];
  $('#fps').options[0].textContent = rates.length ? `The model's (${rates.join(' or ')} fps)` : "The model's";
}

/** "a person jumps": an example sentence for a verb the model was shown alone. */
function exampleOf(verb) {
  if (/(s|sh|ch|x|z|o)$/.test(verb)) return `a person ${verb}es`;
  if (/[^aeiou]y$/.test(verb)) return `a person ${verb.slice(0, -1)}ies`;
  return `a person ${verb}s`;
}

const SHOWN_VERBS = 24; // more are behind "more", so a big model's list does not bury the form

/** The actions each lane's run was shown alone, each a button that adds its example sentence. */
function showKnownActions() {
  const runs = new Map();
  for (const lane of $$('#lanes .lane')) {
    const details = lane.details;
    if (details?.actions?.length) runs.set(`${details.model}/${details.id}`, details);
  }
  const lines = [...runs.values()].map((details) => {
    const line = document.createElement('div');
    line.className = 'known';
    const who = runs.size > 1 ? `${details.model} (run ${details.id}) knows` : 'This model knows';
    line.append(`${who} ${details.actions.length} action${details.actions.length === 1 ? '' : 's'}: `);
    const chips = details.actions.map((verb) => {
      const chip = document.createElement('button');
      chip.type = 'button';
      chip.className = 'chip';
      chip.textContent = verb;
      chip.title = `Add “${exampleOf(verb)}”`;
      chip.addEventListener('click', () => useExample(exampleOf(verb)));
      return chip;
    });
    line.append(...chips.slice(0, SHOWN_VERBS));
    if (chips.length > SHOWN_VERBS) {
      const more = document.createElement('details');
      const summary = document.createElement('summary');
      summary.textContent = `${chips.length - SHOWN_VERBS} more`;
      more.append(summary, ...chips.slice(SHOWN_VERBS));
      line.append(more);
    }
    return line;
  });
  $('#known-actions').replaceChildren(...lines);
  $('#known-actions').hidden = lines.length === 0;
}

// ---- generate: one streamed request per lane and variation, all at once ---------------

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

const mean = (values) => values.reduce((a, b) => a + b, 0) / values.length;

/** One request's progress shown in its lane, whose bar is the mean of its variations'; without a
 *  `status`, the lane's status says that mean. */
function setLaneProgress(job, fraction, status) {
  const lane = job.lane;
  lane.fractions[job.variation] = fraction;
  const done = mean(lane.fractions);
  $('.lane-state', lane).hidden = false;
  $('.lane-progress', lane).value = done;
  $('.lane-status', lane).textContent = status ?? (done === 1 ? 'done' : `${Math.round(done * 100)} %`);
  $('#progress').value = mean($$('#lanes .lane-progress').map((p) => p.value));
}

/** Every lane's request once per variation, lane by lane, the seeds counting up from the form's;
 *  each lane's progress starts again at 0. */
function jobsOf(lanes, shared) {
  const variations = Number($('#variations').value || 1);
  return lanes.flatMap((lane) => {
    lane.fractions = new Array(variations).fill(0);
    const body = { ...shared, ...laneRequest(lane) };
    const seeded = (variation) => ({ lane, variation, body: { ...body, seed: body.seed + variation } });
    return Array.from({ length: variations }, (_, variation) => seeded(variation));
  });
}

/** POST `body` to a sampling endpoint, its progress streamed to `onProgress(fraction, status)`;
 *  the result it ends with. */
async function sample(path, body, onProgress) {
  const response = await api(path, {
    method: 'POST',
    headers: { 'Content-Type': 'application/json', Accept: 'application/x-ndjson' },
    body: JSON.stringify(body),
  });
  let result = null;
  await readLines(response, (message) => {
    if (message.error) throw new Error(message.error);
    if (message.result) result = message.result;
    else if ('queued' in message) onProgress(0, `queued: position ${message.queued}`);
    else if ('progress' in message) onProgress(message.progress);
  });
  if (!result) throw new Error('The server ended its answer without a result.');
  return result;
}

/** One lane's variation sampled; the result remembers its knobs, which its edits are sampled with. */
async function runJob(job) {
  setLaneProgress(job, 0, 'starting…');
  const result = await sample('/api/generate', job.body, (fraction, status) => setLaneProgress(job, fraction, status));
  setLaneProgress(job, 1);
  const { method } = job.body;
  result.sampling = { ...job.body.options, ...(method ? { method } : {}) };
  return result;
}

/** Check the visible inputs against their HTML limits (min, max, step) before sending. */
function formIsValid() {
  const shown = $$('#form input, #form select, #form textarea').filter((el) => el.offsetParent !== null);
  const bad = shown.find((el) => !el.checkValidity());
  if (!bad) return true;
  bad.reportValidity();
  const name = bad.dataset.label || bad.getAttribute('aria-label') || bad.id || 'A field';
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
  const jobs = jobsOf(lanes, shared);
  const outcomes = await Promise.allSettled(jobs.map(runJob));
  button.disabled = false;
  $('#progress').hidden = true;
  reportOutcomes(lanes, jobs, outcomes);
}

/** The results side by side; each failure said once, though every variation of a lane (whose
 *  seed seldom matters to a refusal) fails with the same sentence. */
function reportOutcomes(lanes, jobs, outcomes) {
  const failed = outcomes.map((o, i) => [o, jobs[i]]).filter(([o]) => o.status === 'rejected');
  failed.forEach(([, job]) => setLaneProgress(job, 0, 'failed'));
  const prefix = (lane) => (lanes.length > 1 ? `${laneTitle(lane)}: ` : '');
  showError([...new Set(failed.map(([o, job]) => prefix(job.lane) + o.reason.message))].join(' '));
  const results = outcomes.filter((o) => o.status === 'fulfilled').map((o) => o.value);
  if (results.length) showResults(results);
  showNotices(results);
}

/** What the models did not know of the actions (words never read, verbs never shown alone):
 *  worth knowing, not an error; each said once however many lanes say it. */
function showNotices(results) {
  const notices = [...new Set(results.flatMap((result) => result.notices || []))];
  const items = notices.map((notice) => {
    const item = document.createElement('li');
    item.textContent = notice;
    return item;
  });
  $('#notices ul').replaceChildren(...items);
  $('#notices').hidden = items.length === 0;
}

// ---- results ----------------------------------------------------------------------------

function downloadLinks(result) {
  const box = document.createElement('div');
  box.className = 'downloads';
  for (const [format, href] of Object.entries(result.files || {})) {
    const link = document.createElement('a');
    link.href = withToken(href);
    link.download = '';
    link.dataset.format = format;
    link.textContent = format.toUpperCase();
    box.append(link);
  }
  // the files a result has on an uploaded rig too (the server's motion.<format>?rig=<id>)
  const onRig = (result.on_rig || []).map((format) => $(`a[data-format="${format}"]`, box)).filter(Boolean);
  box.append(...onRig.map(rigLink));
  const bvh = $('a[data-format="bvh"]', box);
  if (bvh) box.append(restPoseChoice(bvh), bvhNote(result.fps));
  return box;
}

/** "BVH on your rig" (GLB, FBX): the result's file on the uploaded rig's skeleton, there while a rig is. */
function rigLink(file) {
  const link = document.createElement('a');
  link.dataset.format = `${file.dataset.format}-rig`;
  link.dataset.base = file.href; // the plain file's: the rig has its own rest pose
  link.download = '';
  link.textContent = `${file.dataset.format.toUpperCase()} on your rig`;
  showRigLink(link);
  return link;
}

function showRigLink(link) {
  link.hidden = !state.rig;
  if (state.rig) link.href = withQuery(link.dataset.base, 'rig', state.rig.id);
}

/** The BVH's rest pose: the skeleton's own (as generated), or a T-pose for tools that expect one. */
function restPoseChoice(link) {
  const base = link.href;
  const label = document.createElement('label');
  label.className = 'rest-pose';
  const select = document.createElement('select');
  select.add(new Option('As generated', ''));
  select.add(new Option('T-pose', 'tpose'));
  select.addEventListener('change', () => { link.href = select.value ? withQuery(base, 'rest', select.value) : base; });
  label.append('BVH rest pose ', select);
  return label;
}

function bvhNote(fps) {
  const note = document.createElement('p');
  note.className = 'bvh-note muted small';
  note.textContent = `The BVH is at ${fps} fps: in Blender's BVH import, tick “Update Scene FPS”.`;
  return note;
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
  if (mlflow.url) {
    // the address is MLflow's UI, which nothing here starts
    const note = document.createElement('span');
    note.className = 'mlflow-note';
    note.append(' (opens with ');
    const command = document.createElement('code');
    command.textContent = 'make ui';
    note.append(command, ' running)');
    line.append(note);
  }
  return line;
}

/** The result's heading for people (model and method), with the generator's exact settings
 *  (its own notation) kept on a line of their own. */
function playerElement(result) {
  const article = document.createElement('article');
  article.className = 'player';
  const title = document.createElement('h3');
  title.className = 'player-title';
  title.textContent = modelTitle(result.model, result.method);
  const meta = document.createElement('p');
  meta.className = 'player-meta muted small';
  meta.textContent = `run ${result.run} · seed ${result.seed} · ${Number(result.seconds).toFixed(1)} s at ${result.fps} fps`;
  article.append(title, meta);
  if (result.describe) {
    const settings = document.createElement('p');
    settings.className = 'player-settings muted small';
    settings.textContent = `Settings: ${result.describe}`;
    article.append(settings);
  }
  const edit = result.settings?.edit;
  if (edit) {
    const line = document.createElement('p');
    line.className = 'player-edit muted small';
    const pin = result.quality?.pin_error_m;
    line.textContent = `Edited: ${edit}${pin === undefined ? '' : `, the pose met within ${Math.round(pin * 1000)} mm`}.`;
    article.append(line);
  }
  return article;
}

/** New results, each a clip of its own, playing from the start. */
function showResults(results) {
  state.clips = results.map((result) => new Clip(result));
  showClips();
  state.clock.play();
}

/** Every clip as it is now (after its edits), with its editor; the playhead stays where it was. */
function showClips() {
  const area = $('#players');
  const time = state.clock.time;
  area.replaceChildren();
  const seek = (seconds) => { state.clock.pause(); state.clock.seek(seconds); };
  area.classList.toggle('many', state.clips.length > 1); // before the players measure their canvases
  state.editors = [];
  const players = state.clips.map((clip) => {
    const { result } = clip;
    const article = playerElement(result);
    area.append(article);
    const player = new SkeletonPlayer(article, result, { onSeek: seek });
    const editor = new ClipEditor(article, clip, player, editing);
    state.editors.push(editor);
    article.append(editor.element, downloadLinks(result), mlflowLine(result.mlflow));
    return player;
  });
  SkeletonPlayer.shareScale(players);
  state.clock.setPlayers(players);
  state.clock.seek(time);
}

/** What the clips' editors share (editor.js, ClipEditor). */
const editing = {
  copied: null,
  clips: () => state.clips,
  show: showClips,
  time: () => state.clock.time,
  copy(pose) {
    this.copied = pose;
    state.editors.forEach((editor) => editor.showCopied());
  },
  /** An edit of `clip` sampled with its knobs, its seed one more than its own, the delivery the
   *  form asks for now. */
  async send(clip, request, onProgress) {
    const { result } = clip;
    const body = { ...request, options: result.sampling || {}, seed: result.seed + 1, ...deliveryRequest() };
    const edited = await sample(`/api/generations/${encodeURIComponent(result.id)}/edit`, body, onProgress);
    edited.sampling = result.sampling;
    return edited;
  },
};

// ---- the user's rig: sent once, every result's BVH then to be had on it ---------------

/** Send the chosen BVH or GLB (and its joint naming: a preset, your YAML map, or detected) to the
 *  server, which keeps it and says how many joints it has and which naming it read them by. */
async function uploadRig() {
  const file = $('#rig-file').files[0];
  const choice = $('#rig-map').value;
  const mapFile = choice === 'yaml' ? $('#rig-map-file').files[0] : undefined;
  $('#rig-map-knob').hidden = choice !== 'yaml';
  // a later choice has the last word, whichever answer comes first
  const unchanged = () => $('#rig-file').files[0] === file && $('#rig-map').value === choice
    && (choice !== 'yaml' || $('#rig-map-file').files[0] === mapFile);
  const limit = state.catalog?.max_rig_bytes;
  if (!file) {
    setRig(null, '');
  } else if (limit && file.size > limit) { // refused here rather than after sending it all
    setRig(null, `${file.name} is ${mebibytes(file.size)}, over the ${mebibytes(limit)} this server takes.`, true);
  } else if (choice === 'yaml' && !mapFile) {
    setRig(null, 'Choose your joint map, a YAML file, below.');
  } else {
    setRig(null, `Reading ${file.name}…`);
    try {
      const sent = mapFile && await (await api('/api/joint-maps', { method: 'POST', body: mapFile })).json();
      const rig = await sendRig(file, sent ? sent.id : choice);
      const naming = mapFile ? `your map (${mapFile.name})` : `${rig.joint_map} map`;
      if (unchanged()) setRig(rig, `Rig: ${rig.joints} joints, ${naming}.`);
    } catch (err) {
      if (unchanged()) setRig(null, err.message, true);
    }
  }
}

/** The server's rig of the file through the joint map ('': detected): the file's bytes are sent once,
 *  then named by their id, so another naming of a character of tens of MB, or the same file chosen
 *  again (its name, size and time alike), does not send it again. */
async function sendRig(file, map) {
  const path = map ? withQuery('/api/rigs', 'joint_map', map) : '/api/rigs';
  const sent = state.rigFile?.file;
  if (sent && ['name', 'size', 'lastModified'].every((key) => sent[key] === file[key])) {
    try {
      return await (await api(withQuery(path, 'file', state.rigFile.id), { method: 'POST' })).json();
    } catch (err) {
      if (err.status !== 404) throw err; // 404: the server no longer has it (it restarted): sent again
    }
  }
  const request = { method: 'POST', headers: { 'Content-Type': 'application/octet-stream' }, body: file };
  const rig = await (await api(path, request)).json();
  state.rigFile = { file, id: rig.file };
  return rig;
}

function mebibytes(bytes) {
  return `${(bytes / 2 ** 20).toFixed(1)} MiB`;
}

/** The rig of the results' "BVH on your rig" links (null: none), and what the server said of it. */
function setRig(rig, message, failed = false) {
  state.rig = rig;
  const status = $('#rig-status');
  status.textContent = message;
  status.hidden = !message;
  status.classList.toggle('failed', failed);
  $$('#players a[data-format$="-rig"]').forEach(showRigLink);
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
  const { models } = state.catalog;
  showRunFacts();
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
  // a narrower form (a scroll bar, a window) can make a sentence need another line
  new ResizeObserver(() => requestAnimationFrame(() => $$('#actions .action-text').forEach(fitHeight)))
    .observe($('#actions'));
  $('#actions').addEventListener('click', onActionButton);
  $('#add-action').addEventListener('click', () => $('.action-text', addAction()).focus());
  $('#split-prompt').addEventListener('click', splitPrompt);
  $$('input[name="mode"]').forEach((radio) => radio.addEventListener('change', showMode));
  $('#compare').addEventListener('click', addCompareLane);
  $('#rig-file').addEventListener('change', uploadRig);
  $('#rig-map').addEventListener('change', uploadRig);
  $('#rig-map-file').addEventListener('change', uploadRig);
  $('#form').addEventListener('submit', (e) => { e.preventDefault(); generate(); });
  $('#token-retry').addEventListener('click', retryWithToken);
  bindTransport();
  showMode();
  loadModels();
}

start();
