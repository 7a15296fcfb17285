// The operator's page: renders the server's state (pushed on /api/events) and sends the
// page's requests to /api/*. Plain JavaScript, no build step, nothing loaded from elsewhere.
'use strict';

const COLOURS = {red: '#ff3b30', green: '#30c552', blue: '#2f6bff', nir: '#b45cf0'};
let state = null;
let selected = null;      // id of the history entry shown under Classify (null: the newest)
let lastAnswer = null;    // the Classify service's answer to this page's last call
let liveShown = null;
const formNote = {};       // why a capture / calibration this page asked for did not start

function el(tag, attrs, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (k === 'class') node.className = v;
    else if (k.startsWith('on')) node.addEventListener(k.slice(2), v);
    else node.setAttribute(k, v);
  }
  for (const c of children.flat()) {
    if (c !== null && c !== undefined) node.append(c instanceof Node ? c : String(c));
  }
  return node;
}

function svg(tag, attrs) {
  const node = document.createElementNS('http://www.w3.org/2000/svg', tag);
  for (const [k, v] of Object.entries(attrs)) node.setAttribute(k, v);
  return node;
}

function clock(t) { return new Date(t * 1000).toLocaleTimeString(); }
function ms(v) { return v === null || v === undefined ? '' : `${v.toFixed(1)} ms`; }

// The stage seen from the camera: each site a cluster of its 4 LEDs (R G B / NIR), lit ones
// coloured with their drive level.
function ledPicture(intensities, size) {
  const stage = state.stage;
  const box = svg('svg', {width: size, height: size, viewBox: `0 0 ${size} ${size}`, class: 'stage'});
  box.append(svg('circle', {cx: size / 2, cy: size / 2, r: size / 2 - 1, fill: '#12151c'}));
  const reach = Math.max(1, ...stage.sites.map(s => Math.hypot(s.x_mm, s.y_mm)));
  const ring = size / 2 - size * 0.14;
  const led = size * 0.04, gap = size * 0.046;
  const offsets = [[-1, -1], [1, -1], [-1, 1], [1, 1]];
  const title = [];
  stage.sites.forEach((site, s) => {
    const cx = size / 2 + site.x_mm / reach * ring, cy = size / 2 - site.y_mm / reach * ring;
    if (size >= 120) {
      const n = svg('text', {x: cx, y: cy + gap * 3.4, 'font-size': size * 0.06, fill: '#8b93a3', 'text-anchor': 'middle'});
      n.textContent = s;
      box.append(n);
    }
    stage.channels.forEach((ch, c) => {
      const v = intensities ? intensities[s * stage.channels.length + c] : 0;
      const lit = v > 0;
      if (lit) title.push(`site ${s} ${ch} ${Math.round(v * 100)} %`);
      box.append(svg('circle', {cx: cx + offsets[c][0] * gap, cy: cy + offsets[c][1] * gap, r: led,
        fill: lit ? COLOURS[ch] : '#2a2f3a', 'fill-opacity': lit ? 0.35 + 0.65 * v : 1,
        stroke: lit ? '#fff' : '#444b59', 'stroke-width': lit ? 0.8 : 0.5,
        'data-led': s * stage.channels.length + c, 'data-lit': lit ? '1' : '0'}));
    });
  });
  const t = svg('title', {});
  t.textContent = title.length ? title.join(', ') : 'all LEDs off';
  box.append(t);
  return box;
}

const CHANNEL_WORDS = {red: 'red', green: 'green', blue: 'blue', nir: 'near-infrared'};

function listWords(items) {
  return items.length <= 1 ? items.join('') : `${items.slice(0, -1).join(', ')} and ${items[items.length - 1]}`;
}

// The LEDs lit, in words: "5 near-infrared LEDs on, at sites 3, 4, 5, 6 and 7 (full power)".
function ledWords(intensities) {
  const chans = state.stage.channels;
  const parts = [];
  chans.forEach((ch, c) => {
    const lit = [];
    intensities.forEach((v, i) => { if (v > 0 && i % chans.length === c) lit.push([Math.floor(i / chans.length), v]); });
    if (!lit.length) return;
    const levels = new Set(lit.map(([, v]) => Math.round(v * 100)));
    const power = levels.size === 1
      ? ([...levels][0] === 100 ? 'full power' : `${[...levels][0]} % power`)
      : lit.map(([s, v]) => `site ${s} ${Math.round(v * 100)} %`).join(', ');
    const word = CHANNEL_WORDS[ch] || ch;
    parts.push(`${lit.length} ${word} LED${lit.length === 1 ? '' : 's'} on, at site${lit.length === 1 ? '' : 's'} `
      + `${listWords(lit.map(([s]) => String(s)))} (${power})`);
  });
  return parts.length ? parts.join('; ') : 'all LEDs off';
}

function patternText(ill) {
  if (!ill) return 'which LEDs were on: not known for this image';
  return `${ledWords(ill.intensities)}. Pattern ${ill.index + 1} of ${ill.count} of request `
    + `${ill.request_id} (trigger ${ill.sequence}); exposure ${(ill.exposure_us / 1000).toFixed(1)} ms`
    + (ill.gain_db === null ? '' : `, gain ${ill.gain_db} dB`);
}

const NODE_OK = ['active', 'running'];

function renderLinks() {
  const links = document.getElementById('links');
  const nodes = Object.entries(state.nodes || {}).map(([name, n]) => {
    const cls = NODE_OK.includes(n.state) ? 'up' : (['stopped', 'not started'].includes(n.state) ? 'down' : 'warn');
    return el('span', {class: `pill node ${cls}`, 'data-node': name, 'data-state': n.state,
      title: `the ${name} node: ${n.state}`}, `${name} ${n.state === 'running' ? '' : n.state}`.trim());
  });
  // a node that is gone takes its topics and services with it: shown as the node, once
  const gone = new Set(Object.entries(state.nodes || {}).filter(([, n]) => !NODE_OK.includes(n.state)).map(([k]) => k));
  const links_ = Object.entries(state.connected).filter(([k]) => !gone.has(k) && !(state.nodes || {})[k]).map(([k, up]) =>
    el('span', {class: `pill ${up ? 'up' : 'down'}`, title: up ? `${k}: available` : `${k}: not available`}, k));
  links.replaceChildren(...nodes, ...links_);
  document.getElementById('classify').disabled = state.classify_running;
}

const START = {driver: 'lightstage up driver', camera: 'lightstage up camera',
  classifier: 'lightstage up classifier', acquisition: 'lightstage up acquisition'};

// What an operator must know about the nodes first: one that stopped, a driver not armed.
function nodeAlerts() {
  const out = [];
  for (const [name, n] of Object.entries(state.nodes || {})) {
    if (n.state === 'stopped') {   // one never started is a pill: a graph may leave it out
      out.push(el('div', {class: 'alert node', 'data-source': name, 'data-node-state': n.state},
        el('span', {class: 'source'}, name),
        'stopped: the node left the graph; start it again (',
        el('code', {}, `${START[name] || 'lightstage up ' + name} --params ...`), ')'));
    } else if (n.lifecycle && n.state !== 'active') {
      const can = name === 'driver' && ['inactive', 'unconfigured'].includes(n.state);
      out.push(el('div', {class: 'alert warning node', 'data-source': name, 'data-node-state': n.state},
        el('span', {class: 'source'}, name),
        `not armed: the ${name} is ${n.state}, so the stage cannot be lit and a Classify will fail. `,
        can ? el('button', {type: 'button', class: 'activate', onclick: () => activate(name)},
          n.state === 'unconfigured' ? 'Configure and activate' : 'Activate')
          : `Restart it (${START[name] || name}).`));
    }
  }
  return out;
}

async function activate(name) {
  try { await post(`/api/nodes/${name}/activate`, {}); } catch (e) { alert(e.message); }
}

function renderAlerts() {
  const alerts = document.getElementById('alerts');
  const errors = [];
  const nodeDown = new Set(Object.entries(state.nodes || {}).filter(([, n]) => ['stopped', 'not started'].includes(n.state)).map(([k]) => k));
  for (const d of state.diagnostics) {
    if (d.level === 'STALE' && nodeDown.has(d.name.split(':')[0])) continue;   // said by its node
    if (d.level === 'ERROR' || d.level === 'STALE') {
      errors.push(el('div', {class: 'alert', 'data-source': d.name},
        el('span', {class: 'source'}, d.name), `${d.level}: ${d.message}`));
    }
  }
  // a status in ERROR stands on top as long as it lasts; its event would say it twice
  const inError = new Set(errors.map(a => a.dataset.source));
  const recent = state.events.filter(e => !(inError.has(e.source) && e.text.startsWith('ERROR'))).slice(0, 6).map(e => el('div', {class: `alert ${e.level}`, 'data-source': e.source},
    el('time', {}, clock(e.time)), el('span', {class: 'source'}, e.source), e.text));
  alerts.replaceChildren(...nodeAlerts(), ...errors, ...recent);
}

function renderLive() {
  const live = state.live;
  const img = document.getElementById('live');
  if (!live) return;
  if (liveShown !== live.stamp_ns) {
    liveShown = live.stamp_ns;
    img.src = `/api/images/live.png?stamp=${live.stamp_ns}`;
  }
  const caption = document.getElementById('live-caption');
  caption.replaceChildren(`${live.width} x ${live.height}, received ${clock(live.received)}; brightest pixel `
    + `${(live.peak * 100).toFixed(1)} % of full scale`,
    live.saturated ? el('span', {class: 'saturated'}, ' — near full scale: likely saturated; '
      + 'lower the exposure or the gain') : '');
  caption.dataset.saturated = live.saturated ? '1' : '0';
  document.getElementById('live-leds').replaceChildren(ledPicture(live.illumination && live.illumination.intensities, 150));
  document.getElementById('live-pattern').textContent = patternText(live.illumination);
}

function scoreBars(names, scores) {
  const box = document.getElementById('scores');
  if (!scores.length) { box.replaceChildren(); return; }
  const lo = Math.min(0, ...scores), hi = Math.max(0, ...scores);
  const span = hi - lo || 1, zero = (0 - lo) / span * 100;
  const best = scores.indexOf(Math.max(...scores));
  const order = scores.map((s, i) => i).sort((a, b) => scores[b] - scores[a]);
  box.replaceChildren(...order.flatMap(i => {
    const v = scores[i];
    const left = v >= 0 ? zero : (v - lo) / span * 100, width = Math.abs(v) / span * 100;
    const bar = el('div', {class: 'bar'}, el('span', {class: i === best ? 'best' : '', style: `left:${left}%;width:${width}%`}),
      el('span', {class: 'zero', style: `left:${zero}%`}));
    return [el('span', {class: 'score-name'}, names[i]), bar, el('span', {class: 'muted'}, (v >= 0 ? '+' : '') + v.toFixed(3))];
  }));
}

function probabilityBars(names, probabilities) {
  const box = document.getElementById('scores');
  const order = probabilities.map((p, i) => i).sort((a, b) => probabilities[b] - probabilities[a]);
  box.replaceChildren(...order.flatMap((i, rank) => [
    el('span', {class: 'score-name'}, names[i]),
    el('div', {class: 'bar probability'}, el('span', {class: rank === 0 ? 'best' : '',
      style: `left:0%;width:${(100 * probabilities[i]).toFixed(1)}%`})),
    el('span', {class: 'muted'}, `${(100 * probabilities[i]).toFixed(1)} %`)]));
}

// an answer in words: what was decided, and what to do about it (colour is never the only cue)
function decisionText(a) {
  if (!a.success) return '';
  const p = a.probabilities || [];
  if (!p.length) return 'uncalibrated classifier: scores only';
  const order = p.map((v, i) => i).sort((x, y) => p[y] - p[x]);
  const pct = i => `${a.class_names[i]} ${(100 * p[i]).toFixed(1)} %`;
  if (a.decision === 'unsure') return `not sure: ${pct(order[0])}, ${pct(order[1])} — look again or ask a person`;
  if (a.decision === 'unknown') {
    const n = a.novelty === null || a.novelty === undefined ? '' : ` (novelty ${a.novelty.toFixed(2)})`;
    return `unknown object: unlike every trained class${n} — not ${a.label}`;
  }
  return `accepted: ${(100 * p[order[0]]).toFixed(1)} % sure`;
}

function exposures(a) {
  const budget = a.images_budget || a.images_used;
  return budget && budget !== a.images_used ? `${a.images_used} of ${budget}` : `${a.images_used}`;
}

function shownEntry() {
  if (selected !== null) return state.history.find(h => h.id === selected) || null;
  return state.history[0] || null;
}

function renderAnswer() {
  const label = document.getElementById('label');
  const entry = shownEntry();
  // this page's own answer first (a failed call may have no history entry yet), then the history
  const a = selected === null && lastAnswer ? lastAnswer : entry;
  if (!a) return;
  const decision = a.success ? (a.decision || 'accepted') : '';
  label.textContent = a.success ? a.label : `classification failed: ${a.message}`;
  label.className = a.success ? (decision === 'accepted' ? '' : decision) : 'failed';
  label.dataset.success = a.success ? '1' : '0';
  const said = document.getElementById('decision');
  said.textContent = decisionText(a);
  said.className = `decision ${decision}`;
  said.dataset.decision = decision;
  document.getElementById('times').textContent = a.success
    ? `${exposures(a)} exposures, acquisition ${ms(a.acquisition_ms)}, compute ${ms(a.compute_ms)}` : '';
  if (a.probabilities && a.probabilities.length) probabilityBars(a.class_names || [], a.probabilities);
  else scoreBars(a.class_names || [], a.scores || []);
  const thumbs = document.getElementById('class-images');
  const images = entry && (!lastAnswer || selected !== null || sameClassification(entry, lastAnswer)) ? entry.images : [];
  thumbs.replaceChildren(...images.map(i => el('div', {class: 'thumb'},
    i.image ? el('img', {src: `/api/images/${i.image.stamp_ns}.png`, alt: `image of trigger ${i.sequence}`}) : el('div', {}, 'image not received'),
    el('div', {class: 'leds'}, ledPicture(i.illumination && i.illumination.intensities, 90)),
    `trigger ${i.sequence}`)));
}

function sameClassification(entry, answer) {
  return entry.success === answer.success && entry.label === answer.label
    && entry.acquisition_ms === answer.acquisition_ms;
}

function historyLabel(h) {
  const p = h.probabilities || [];
  const top = p.length ? ` ${(100 * Math.max(...p)).toFixed(0)} %` : '';
  if (h.decision === 'unsure') return el('td', {class: 'unsure', 'data-decision': 'unsure'}, `not sure (${h.label}${top})`);
  if (h.decision === 'unknown') return el('td', {class: 'unknown', 'data-decision': 'unknown'}, 'unknown object');
  return el('td', {'data-decision': 'accepted'}, h.label + top);
}

function renderHistory() {
  const body = document.querySelector('#history tbody');
  body.replaceChildren(...state.history.map(h => el('tr', {
      class: h.id === selected ? 'selected' : '', 'data-id': h.id,
      onclick: () => { selected = selected === h.id ? null : h.id; lastAnswer = null; render(); }},
    el('td', {}, clock(h.time)),
    h.success ? historyLabel(h) : el('td', {class: 'failed', title: h.message}, 'failed: ' + h.message.slice(0, 60)),
    el('td', {}, h.success ? exposures(h) : ''), el('td', {}, h.success ? ms(h.acquisition_ms) : ''),
    el('td', {}, h.success ? ms(h.compute_ms) : ''))));
}

function renderDiagnostics() {
  const box = document.getElementById('diagnostics');
  if (!state.diagnostics.length) return;
  box.replaceChildren(...state.diagnostics.map(d => el('div', {class: `diag ${d.level}`, 'data-name': d.name},
    el('div', {}, el('span', {class: 'level'}, d.level), el('strong', {}, d.name), ': ', d.message),
    el('details', {}, el('summary', {}, `${Object.keys(d.values).length} values, last report ${clock(d.received)}`),
      el('dl', {}, Object.entries(d.values).flatMap(([k, v]) => [el('dt', {}, k), el('dd', {}, v)]))))));
}

function jobResult(j) {
  const r = j.result || {};
  if (j.state !== 'succeeded') return null;
  if (j.kind === 'capture') {
    return el('div', {class: 'result'}, `${r.images_captured} images written to `, el('code', {}, r.model_dir),
      r.saturated_pixels ? el('span', {class: 'saturated'}, ` — ${r.saturated_pixels} saturated pixels`) : '',
      ` (${(r.elapsed_s || 0).toFixed(1)} s)`);
  }
  return el('div', {class: 'result'},
    el('div', {}, 'noise file: ', r.output_path ? el('code', {}, r.output_path) : 'not written (no file named)'),
    el('div', {}, 'plot: ', r.plot_path ? el('code', {}, r.plot_path) : 'not written (no file named)'),
    el('div', {}, `photon noise sigma_p2 ${Number(r.sigma_p2).toPrecision(4)}, read noise sigma_r2 `
      + `${Number(r.sigma_r2).toPrecision(4)} at ${r.gain_db} dB, ${r.exposure_ms} ms`),
    r.plot_path ? el('img', {class: 'plot', src: `/api/jobs/${j.id}/plot.png`, alt: 'the noise characteristic plot'}) : null);
}

function jobBox(j) {
  const running = ['starting', 'running', 'cancelling'].includes(j.state);
  return el('div', {class: `job ${j.state}`, 'data-id': j.id, 'data-state': j.state},
    el('div', {}, el('strong', {}, j.kind), ` ${j.state}`, j.progress ? `: ${j.progress}` : '',
      running && j.state !== 'cancelling' ? el('button', {type: 'button', class: 'small', onclick: cancelJob}, 'Cancel') : null),
    el('div', {class: 'progress'}, el('span', {style: `width:${Math.round(j.fraction * 100)}%`})),
    j.message ? el('div', {class: 'muted'}, j.message) : null, jobResult(j));
}

function renderJobs() {
  // the latest job of each kind beside its button; the ones before below
  const latest = {};
  for (const j of state.jobs) if (!latest[j.kind]) latest[j.kind] = j;
  for (const kind of ['capture', 'calibrate']) {
    const box = document.getElementById(`${kind}-job`);
    const note = formNote[kind] ? el('div', {class: 'job failed note'}, formNote[kind]) : null;
    box.replaceChildren(...[note, latest[kind] ? jobBox(latest[kind]) : null].filter(Boolean));
  }
  const shown = new Set(Object.values(latest).map(j => j.id));
  document.getElementById('jobs').replaceChildren(...state.jobs.filter(j => !shown.has(j.id)).slice(0, 4).map(jobBox));
}

function renderDefaults() {
  const d = state.defaults || {};
  const say = (id, text) => { const n = document.getElementById(id); if (n) n.textContent = text; };
  say('default-frames', d.frames_averaged === undefined
    ? '0 = the acquisition node\'s frames_averaged' : `0 = ${d.frames_averaged} (the node's frames_averaged)`);
  say('default-levels', d.calibration_levels === undefined
    ? '0 = the acquisition node\'s calibration_frames / calibration_levels'
    : `0 = ${d.calibration_frames} frames per level, ${d.calibration_levels} levels (the node's settings)`);
}

function render() {
  if (!state) return;
  renderLinks(); renderAlerts(); renderLive(); renderAnswer(); renderHistory(); renderDiagnostics(); renderJobs();
  renderDefaults();
}

async function post(path, body) {
  const r = await fetch(path, {method: 'POST', headers: {'Content-Type': 'application/json'}, body: JSON.stringify(body)});
  const data = await r.json().catch(() => ({error: `HTTP ${r.status}`}));
  if (!r.ok) throw new Error(data.error || `HTTP ${r.status}`);
  return data;
}

function say(text) { document.getElementById('classify-status').textContent = text; }

async function classify() {
  const button = document.getElementById('classify');
  button.disabled = true;
  say('classifying ...');
  document.getElementById('label').dataset.pending = '1';
  try {
    lastAnswer = await post('/api/classify', {max_images: Number(document.getElementById('max-images').value) || 0});
    selected = null;
    say('');
  } catch (e) {
    lastAnswer = {success: false, message: e.message};
    say('');
  } finally {
    delete document.getElementById('label').dataset.pending;
    button.disabled = false;
    render();
  }
}

async function cancelJob() {
  try { await post('/api/jobs/cancel', {}); } catch (e) { alert(e.message); }
}

function formBody(form) {
  const body = {};
  for (const input of form.querySelectorAll('input')) {
    if (input.type === 'checkbox') body[input.name] = input.checked;
    else if (input.type === 'number') body[input.name] = Number(input.value) || 0;
    else body[input.name] = input.value;
  }
  return body;
}

for (const [id, path] of [['capture-form', '/api/capture'], ['calibrate-form', '/api/calibrate']]) {
  document.getElementById(id).addEventListener('submit', async (ev) => {
    ev.preventDefault();
    const kind = id.split('-')[0];
    formNote[kind] = '';
    try { await post(path, formBody(ev.target)); } catch (e) { formNote[kind] = `not started: ${e.message}`; }
    if (state) render();
  });
}
document.getElementById('classify').addEventListener('click', classify);

function connect() {
  const ws = new WebSocket(`ws://${location.host}/api/events`);
  ws.onmessage = (m) => {
    const incoming = JSON.parse(m.data);
    // the history comes only when it changed: keep the one this page has
    if (!('history' in incoming) && state) incoming.history = state.history;
    state = incoming;
    render();
  };
  ws.onclose = () => {
    if (state) { state.connected = {page: false}; renderLinks(); }
    setTimeout(connect, 1000);
  };
}
connect();
