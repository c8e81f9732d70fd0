// Models: an editor for a text model (docs/text-models.md) checked by
// riccatid as one types (CreateModel with validateOnly: nothing stored), its
// error shown at its line; uploading it, then Identify with it. Below, every
// model the tenant can use (the models directory's and its own text models)
// with states, parameters (units, defaults, bounds), inputs and outputs, the
// check of their Jacobians and a text model's equations and revisions.
import {api} from '../api.js';
import {clear, errorBox, fmt, h, num} from '../dom.js';

// How long the editor waits after the last key before it asks for a check.
const kCheckDelayMs = 400;
const kDraftKey = 'riccati.model-draft';

const kExample = `model: my_tank
description: One tank, outflow k*sqrt(h)
states:     {h: {unit: m}}
inputs:     {F: {unit: m^3/s}}
parameters:
  A: {value: 10,   min: 0, unit: m^2}
  k: {value: 0.08, min: 0, unit: m^2.5/s}
der:
  h: (F - k * sqrt(max(h, 0))) / A
outputs:
  h: h
`;

// "editor:4:10: unexpected ')' ..." -> {line: 4, column: 10}; null when the
// message names no place.
function placeOf(message) {
  const m = /^[^\n]*?:(\d+):(\d+): /.exec(message || '');
  return m ? {line: Number(m[1]), column: Number(m[2])} : null;
}

const withUnit = (name, unit) => (unit ? `${name} [${unit}]` : name);
const named = (names, units) => (names || []).map((n, i) => withUnit(n, (units || [])[i])).join(', ') || '–';

function modelPanel(m) {
  const units = m.paramUnits || [];
  const text = m.text;
  const revision = text && num(text.revision) > 0 ? `@${num(text.revision)}` : '';
  return h('section', {class: 'panel', 'data-model': m.name},
    h('h2', {}, h('a', {href: '#/models/' + encodeURIComponent(m.name)}, m.name), ' ',
      h('span', {class: 'muted'}, m.version || '', text ? (revision ? ` · text model ${revision}` : ' · text model') : ' · plugin')),
    h('p', {}, m.description || ''),
    h('p', {}, h('b', {}, 'States: '), named(m.stateNames, m.stateUnits), ' · ',
      h('b', {}, 'Inputs: '), named(m.inputNames, m.inputUnits), ' · ',
      h('b', {}, 'Outputs: '), named(m.outputNames, m.outputUnits)),
    h('table', {},
      h('thead', {}, h('tr', {}, ['Parameter', 'Unit', 'Default', 'Lower', 'Upper'].map((c) => h('th', {}, c)))),
      h('tbody', {}, (m.paramNames || []).map((p, i) => h('tr', {'data-param': p}, h('th', {}, p),
        h('td', {class: 'unit'}, units[i] || ''),
        h('td', {class: 'num'}, fmt((m.thetaDefault || [])[i], 5)), h('td', {class: 'num'}, fmt((m.thetaLower || [])[i])),
        h('td', {class: 'num'}, fmt((m.thetaUpper || [])[i])))))),
    text && (text.equations || []).length ? h('pre', {class: 'equations'}, text.equations.join('\n')) : null,
    text && (text.revisions || []).length > 1
      ? h('p', {class: 'muted'}, 'Stored revisions: ', text.revisions.map((r) => `${m.name}@${num(r)}`).join(', ')) : null,
    h('p', {class: 'muted'}, `Jacobians: f ${m.exactFJacobian ? 'exact' : 'finite differences'}, g ${m.exactGJacobian ? 'exact' : 'finite differences'}`,
      m.jacobianCheck && m.jacobianCheck.checked ? `; checked against finite differences: ${m.jacobianCheck.agrees ? 'agree' : 'DISAGREE'} (max error ${fmt(m.jacobianCheck.maxError, 2)})` : '',
      num(m.ndof) ? `; mechanical, ${num(m.ndof)} degrees of freedom` : ''),
    h('p', {}, h('a', {class: 'button', href: `#/identify?model=${encodeURIComponent(m.name)}`}, 'Identify with it')));
}

// The editor: a textarea with line numbers beside it; the line of an error
// is marked there and the message (line, column, the line and a caret) below.
function editor(onStored, signal) {
  const source = h('textarea', {id: 'model-source', spellcheck: 'false', rows: 18, wrap: 'off'});
  source.value = sessionStorage.getItem(kDraftKey) || kExample;
  const gutter = h('pre', {class: 'gutter', id: 'model-gutter', 'aria-hidden': 'true'});
  const check = h('div', {id: 'model-check', class: 'muted'}, 'Checking…');
  const upload = h('button', {class: 'primary', id: 'model-upload', type: 'button', disabled: true}, 'Upload');
  const stored = h('div', {id: 'model-stored'});
  let pending = null;   // the check's timer
  let inFlight = null;  // the check's request, aborted by a newer one

  const drawGutter = (badLine) => {
    const lines = source.value.split('\n').length;
    clear(gutter, Array.from({length: lines}, (_, i) =>
      h('span', {class: i + 1 === badLine ? 'bad' : '', 'data-line': i + 1}, String(i + 1), '\n')));
    gutter.scrollTop = source.scrollTop;
  };
  const runCheck = async () => {
    if (inFlight) inFlight.abort();
    inFlight = new AbortController();
    const mine = inFlight;
    signal.addEventListener('abort', () => mine.abort());
    try {
      const m = await api('POST', '/models', {source: source.value, fileName: 'editor', validateOnly: true},
        {signal: mine.signal});
      drawGutter(0);
      clear(check, h('span', {class: 'ok'}, '✓ '), `${m.name}: ${(m.stateNames || []).length} states, `,
        `${(m.paramNames || []).length} parameters, ${(m.inputNames || []).length} inputs, `,
        `${(m.outputNames || []).length} outputs; Jacobians `,
        m.jacobianCheck && m.jacobianCheck.checked && !m.jacobianCheck.agrees ? 'DISAGREE with finite differences' : 'exact');
      check.className = '';
      upload.disabled = false;
    } catch (err) {
      if (err.name === 'AbortError') return;
      const message = String(err.message).replace(/ \(HTTP \d+\)$/, '');
      const place = placeOf(message);
      drawGutter(place ? place.line : 0);
      clear(check, place ? h('b', {id: 'model-error-line'}, `Line ${place.line}, column ${place.column}: `) : null,
        h('pre', {class: 'error', id: 'model-error'}, message));
      check.className = '';
      upload.disabled = true;
    }
  };
  source.addEventListener('input', () => {
    sessionStorage.setItem(kDraftKey, source.value);
    drawGutter(Number(gutter.querySelector('.bad')?.dataset.line || 0));
    upload.disabled = true;
    clearTimeout(pending);
    pending = setTimeout(runCheck, kCheckDelayMs);
  });
  source.addEventListener('scroll', () => { gutter.scrollTop = source.scrollTop; });
  upload.addEventListener('click', async () => {
    upload.disabled = true;
    try {
      const m = await api('POST', '/models', {source: source.value, fileName: 'editor'}, {signal});
      const name = `${m.name}@${num(m.text && m.text.revision)}`;
      clear(stored, h('p', {class: 'ok'}, `Stored ${name}. `,
        h('a', {class: 'button primary', id: 'model-identify', href: `#/identify?model=${encodeURIComponent(m.name)}`},
          `Identify with ${m.name}`)));
      onStored();
    } catch (err) {
      clear(stored, errorBox(err));
    } finally {
      upload.disabled = false;
    }
  });
  signal.addEventListener('abort', () => clearTimeout(pending));
  drawGutter(0);
  runCheck();
  return h('section', {class: 'panel', id: 'model-editor'},
    h('h2', {}, 'Write a text model'),
    h('p', {class: 'muted'}, 'YAML as docs/text-models.md describes; riccatid checks it as you type and stores it, as ',
      h('code', {}, 'riccati models add'), ' does, when you upload it.'),
    h('div', {class: 'editor'}, gutter, source), check, h('p', {}, upload), stored);
}

export async function show(main, r, signal) {
  const list = h('div', {id: 'model-list'});
  const drawList = async () => {
    const models = (await api('GET', '/models', undefined, {signal})).models || [];
    const shown = r.id ? models.filter((m) => m.name === r.id) : models;
    clear(list, shown.map(modelPanel));
  };
  if (r.id) {
    clear(main, h('h1', {}, `Model ${r.id}`), list);
  } else {
    clear(main, h('h1', {}, 'Models'), editor(() => drawList().catch(() => {}), signal), h('h2', {}, 'Models you can use'), list);
  }
  await drawList();
}
