// Identify: model, dataset, method and filter, and a form for every setting
// labelled with the model's names; submitting opens the job's page
// (#/jobs/<id>: live progress, traces, the result).
import {api} from '../api.js';
import {clear, errorBox, fmt, h, num} from '../dom.js';

const kMethods = [['IDENTIFICATION_METHOD_FILTER', 'Iterated filter (1999 toolbox)'],
  ['IDENTIFICATION_METHOD_OE', 'Output error'], ['IDENTIFICATION_METHOD_ML', 'Maximum likelihood']];
const kFilters = [['FILTER_KIND_EKF', 'EKF'], ['FILTER_KIND_UKF', 'UKF']];
const kIntegrators = [['INTEGRATOR_KIND_RK4', 'RK4'], ['INTEGRATOR_KIND_RK3', 'RK3'],
  ['INTEGRATOR_KIND_CVODE_BDF', 'CVODE BDF'], ['INTEGRATOR_KIND_CVODE_ADAMS', 'CVODE Adams'],
  ['INTEGRATOR_KIND_ARKODE_ERK', 'ARKODE ERK'], ['INTEGRATOR_KIND_DOP853', 'DOP853 (8th order)']];
const kHolds = [['HOLD_ORDER_ZERO', 'zero order'], ['HOLD_ORDER_FIRST', 'first order']];

export function select(id, options, value) {
  return h('select', {id}, options.map(([v, label]) => h('option', {value: v, selected: v === value}, label)));
}

function numberInput(id, value, step = 'any') {
  return h('input', {type: 'number', id, step, value: Number.isFinite(value) ? String(value) : ''});
}

const value = (id) => document.getElementById(id).value;
const number = (id) => {
  const v = value(id).trim();
  return v === '' ? undefined : Number(v);
};

export async function show(main, r, signal) {
  const [models, datasets] = await Promise.all([api('GET', '/models', undefined, {signal}),
    api('GET', '/datasets', undefined, {signal})]);
  const modelList = models.models || [];
  const datasetList = datasets.datasets || [];
  const modelName = r.query.get('model') || (modelList.find((m) => m.name === 'two_tank') || modelList[0] || {}).name;
  const modelSelect = select('model', modelList.map((m) => [m.name, m.name]), modelName);
  const datasetSelect = select('dataset', datasetList.map((d) => [d.id, `${d.name} (${num(d.samples)} samples)`]),
    r.query.get('dataset') || (datasetList[0] || {}).id);
  const settings = h('div', {id: 'settings'});
  const status = h('div', {id: 'identify-status'});
  const submit = h('button', {class: 'primary', id: 'identify-submit', type: 'submit'}, 'Identify');
  const form = h('form', {id: 'identify'},
    h('div', {class: 'panel row'},
      h('label', {}, 'Model', modelSelect),
      h('label', {}, 'Dataset', datasetSelect),
      h('label', {}, 'Method', select('method', kMethods, r.query.get('method') || kMethods[0][0])),
      h('label', {}, 'Filter', select('filter', kFilters, kFilters[0][0])),
      h('label', {}, 'Passes', numberInput('passes', 10, 1)),
      h('label', {}, 'Filter passes first (OE, ML)', numberInput('init-passes', 0, 1))),
    settings, h('p', {}, submit), status);
  const draw = () => {
    const m = modelList.find((x) => x.name === modelSelect.value);
    clear(settings, m ? settingsFor(m) : h('p', {class: 'muted'}, 'No models loaded.'));
    history.replaceState(null, '', `#/identify?model=${encodeURIComponent(modelSelect.value)}&dataset=${encodeURIComponent(datasetSelect.value || '')}`);
  };
  modelSelect.addEventListener('change', draw);
  datasetSelect.addEventListener('change', draw);
  form.addEventListener('submit', async (e) => {
    e.preventDefault();
    const m = modelList.find((x) => x.name === modelSelect.value);
    submit.disabled = true;
    try {
      const job = await api('POST', '/jobs/identification', spec(m, datasetSelect.value));
      location.hash = '#/jobs/' + encodeURIComponent(job.id);
    } catch (err) {
      clear(status, errorBox(err));
      submit.disabled = false;
    }
  });
  clear(main, h('h1', {}, 'Identify'),
    datasetList.length ? null : h('p', {class: 'warn'}, 'No datasets yet: ', h('a', {href: '#/datasets'}, 'upload one'), ' first.'),
    form);
  draw();
}

// "A1 [m^2]": a name with the unit the model declares, if any.
const label = (name, unit) => (unit ? `${name} [${unit}]` : name);

function settingsFor(m) {
  const states = m.stateNames || [], params = m.paramNames || [], outputs = m.outputNames || [];
  const paramUnits = m.paramUnits || [], stateUnits = m.stateUnits || [], outputUnits = m.outputUnits || [];
  const theta = (m.thetaDefault || []).map(num), lower = (m.thetaLower || []).map(num), upper = (m.thetaUpper || []).map(num);
  return [
    h('fieldset', {}, h('legend', {}, 'Parameters'),
      h('table', {id: 'parameters'},
        h('thead', {}, h('tr', {}, ['Parameter', 'Start θ0', 'P0 (variance)', 'Q (intensity)', 'Lower bound', 'Upper bound', 'Fixed'].map((c) => h('th', {}, c)))),
        h('tbody', {}, params.map((p, i) => h('tr', {'data-param': p},
          h('th', {}, label(p, paramUnits[i])),
          h('td', {}, numberInput('theta0-' + p, theta[i])),
          h('td', {}, numberInput('p0-' + p, Math.max(1, theta[i] * theta[i] / 4))),
          h('td', {}, numberInput('q-' + p, 0)),
          h('td', {}, numberInput('lower-' + p, lower[i])),
          h('td', {}, numberInput('upper-' + p, upper[i])),
          h('td', {}, h('input', {type: 'checkbox', id: 'fixed-' + p}))))))),
    h('fieldset', {}, h('legend', {}, 'States'),
      h('label', {class: 'inline'}, h('input', {type: 'checkbox', id: 'x0-first', checked: true}),
        'Start each state with an output of its name at its first measurement (the toolbox\'s Y(t0))'),
      h('table', {id: 'states'},
        h('thead', {}, h('tr', {}, ['State', 'x0', 'P0 (variance)', 'Q (intensity)'].map((c) => h('th', {}, c)))),
        h('tbody', {}, states.map((s, i) => h('tr', {'data-state': s},
          h('th', {}, label(s, stateUnits[i])), h('td', {}, numberInput('x0-' + s, 0)), h('td', {}, numberInput('p0-' + s, 0)),
          h('td', {}, numberInput('q-' + s, 0))))))),
    h('fieldset', {}, h('legend', {}, 'Measurements'),
      outputs.map((y, i) => h('label', {}, `R of ${label(y, outputUnits[i])} (variance)`, numberInput('r-' + y, 1e-3)))),
    h('fieldset', {}, h('legend', {}, 'Integration'),
      h('label', {}, 'Integrator', select('integrator', kIntegrators, kIntegrators[0][0])),
      h('label', {}, 'Substeps per sample', numberInput('substeps', 10, 1)),
      h('label', {}, 'Input hold', select('hold', kHolds, kHolds[0][0]))),
    h('p', {class: 'muted'}, `${m.name} ${m.version || ''}: ${m.description || ''}`),
  ];
}

// The IdentificationSpec of the form, in the proto's JSON mapping.
function spec(m, datasetId) {
  const states = m.stateNames || [], params = m.paramNames || [], outputs = m.outputNames || [];
  const nz = [...states, ...params];
  const q = nz.map((n) => number('q-' + n) || 0);
  const out = {
    model: m.name,
    datasetId,
    method: value('method'),
    passes: number('passes') || 1,
    initPasses: number('init-passes') || 0,
    filter: {
      kind: value('filter'),
      hold: value('hold'),
      integrator: {kind: value('integrator'), substeps: number('substeps') || 10},
      r: {diagonal: {values: outputs.map((y) => number('r-' + y) ?? 0)}},
    },
    initialState: document.getElementById('x0-first').checked ? {firstMeasurement: true}
      : {x0: states.map((s) => number('x0-' + s) ?? 0)},
    theta0: params.map((p, i) => number('theta0-' + p) ?? num((m.thetaDefault || [])[i])),
    p0: {diagonal: {values: nz.map((n) => number('p0-' + n) ?? 0)}},
    bounds: params.map((p) => ({name: p, lower: number('lower-' + p), upper: number('upper-' + p)})),
    fixed: params.filter((p) => document.getElementById('fixed-' + p).checked).map((p) => ({name: p})),
  };
  if (q.some((v) => v !== 0)) out.filter.q = {diagonal: {values: q}};
  return out;
}

export {fmt};
