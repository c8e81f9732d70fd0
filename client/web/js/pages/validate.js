// Validate: simulate the model over a dataset's inputs with an
// identification's estimate (or given parameters) and compare with what was
// measured, per output, with fit % as MATLAB's compare; the comparison
// opens on the job's page.
import {api} from '../api.js';
import {clear, enumOrDefault, errorBox, h, num, when} from '../dom.js';
import {select} from './identify.js';

// "FILTER", "OE", "ML"; unspecified is the iterated filter (jobs.proto).
const methodName = (m) => enumOrDefault(m, 'IDENTIFICATION_METHOD_', 'FILTER');

export async function show(main, r, signal) {
  const [models, datasets, jobs] = await Promise.all([api('GET', '/models', undefined, {signal}),
    api('GET', '/datasets', undefined, {signal}), api('GET', '/jobs', undefined, {signal})]);
  const modelList = models.models || [], datasetList = datasets.datasets || [];
  const identifications = (jobs.jobs || []).filter((j) => j.identification && j.state === 'JOB_STATE_SUCCEEDED');
  // The parameters' source first: the model and the dataset follow the job
  // chosen (its parameters fit its model only), unless the link names them.
  const defaultSource = r.query.get('job') || (identifications[0] || {id: ''}).id;
  const job = identifications.find((j) => j.id === defaultSource);
  const modelSelect = select('validate-model', modelList.map((m) => [m.name, m.name]),
    (job && job.identification.model) || r.query.get('model') || (modelList[0] || {}).name);
  const datasetSelect = select('validate-dataset', datasetList.map((d) => [d.id, d.name]),
    r.query.get('dataset') || (job && job.identification.datasetId) || (datasetList[0] || {}).id);
  const source = select('validate-source', [
    ...identifications.map((j) => [j.id, `estimate of job ${j.id} (${j.identification.model}, ${methodName(j.identification.method)}, ${when(j.finished)})`]),
    ['', 'the parameters below']], defaultSource);
  source.addEventListener('change', () => {
    const chosen = identifications.find((j) => j.id === source.value);
    if (!chosen) return;
    modelSelect.value = chosen.identification.model;
    if (datasetList.some((d) => d.id === chosen.identification.datasetId)) datasetSelect.value = chosen.identification.datasetId;
  });
  // A model the chosen job was not of: its own parameters, then.
  modelSelect.addEventListener('change', () => {
    const chosen = identifications.find((j) => j.id === source.value);
    if (chosen && chosen.identification.model !== modelSelect.value) source.value = '';
  });
  const thetaBox = h('div', {class: 'row', id: 'validate-theta'});
  const drawTheta = () => {
    const m = modelList.find((x) => x.name === modelSelect.value) || {};
    clear(thetaBox, (m.paramNames || []).map((p, i) => h('label', {}, p,
      h('input', {type: 'number', step: 'any', id: 'vtheta-' + p, value: String(num((m.thetaDefault || [])[i]))}))));
    thetaBox.style.display = source.value ? 'none' : '';
  };
  modelSelect.addEventListener('change', drawTheta);
  source.addEventListener('change', drawTheta);
  // K samples ahead with the job's filter and noise model (jobs.proto
  // ValidationSpec.horizon): an estimate of a job only; empty is the simulation.
  const horizon = h('input', {type: 'number', min: '1', step: '1', id: 'validate-horizon', placeholder: 'simulation'});
  const horizonLabel = h('label', {}, 'Horizon (samples ahead; empty: simulation)', horizon);
  const drawHorizon = () => { horizonLabel.style.display = source.value ? '' : 'none'; };
  source.addEventListener('change', drawHorizon);
  modelSelect.addEventListener('change', drawHorizon);
  const first = h('input', {type: 'checkbox', id: 'validate-x0-first', checked: true});
  const status = h('div', {id: 'validate-status'});
  const submit = h('button', {class: 'primary', id: 'validate-submit', type: 'submit'}, 'Validate');
  const form = h('form', {class: 'panel', id: 'validate'},
    h('div', {class: 'row'}, h('label', {}, 'Model', modelSelect), h('label', {}, 'Dataset', datasetSelect),
      h('label', {}, 'Parameters', source)),
    thetaBox, h('div', {class: 'row'}, horizonLabel),
    h('label', {class: 'inline'}, first, 'Start each state with an output of its name at its first measurement'),
    h('p', {}, submit), status);
  form.addEventListener('submit', async (e) => {
    e.preventDefault();
    const m = modelList.find((x) => x.name === modelSelect.value) || {};
    const spec = {model: m.name, datasetId: datasetSelect.value,
      initialState: first.checked ? {firstMeasurement: true} : {x0: (m.stateNames || []).map(() => 0)}};
    if (source.value && horizon.value !== '') {
      const k = Number(horizon.value);
      if (!(Number.isInteger(k) && k >= 1)) {
        return clear(status, errorBox(new Error('horizon: a whole number of samples, at least 1 (empty: the simulation)')));
      }
      spec.horizon = k;
    }
    if (source.value) spec.identificationJobId = source.value;
    else spec.theta = {values: (m.paramNames || []).map((p) => Number(document.getElementById('vtheta-' + p).value))};
    submit.disabled = true;
    try {
      const job = await api('POST', '/jobs/validation', spec);
      location.hash = '#/jobs/' + encodeURIComponent(job.id);
    } catch (err) {
      clear(status, errorBox(err));
      submit.disabled = false;
    }
  });
  clear(main, h('h1', {}, 'Validate'), h('p', {class: 'muted'}, 'Simulate the model open loop over the dataset\'s inputs (or, with a job\'s estimate and a horizon, predict each sample K samples ahead with the job\'s filter) and compare with its outputs (fit % as MATLAB\'s compare: 100 is perfect).'), form);
  drawTheta();
  drawHorizon();
}
