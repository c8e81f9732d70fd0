// Datasets: upload (drag and drop, column mapping with a model's names
// proposed), list, delete, and a plot of every signal (#/datasets/<id>).
import {api} from '../api.js';
import {clear, errorBox, fmt, h, num, row, when} from '../dom.js';
import {plot} from '../plot.js';

export async function show(main, r, signal) {
  if (r.id) return showOne(main, r.id, signal);
  const models = await api('GET', '/models', undefined, {signal});
  const box = h('div', {id: 'datasets-box'});
  const refresh = async () => clear(box, table((await api('GET', '/datasets', undefined, {signal})).datasets || [], refresh));
  await refresh();
  clear(main, h('h1', {}, 'Datasets'), uploadForm(models.models || [], refresh), box);
}

function table(datasets, refresh) {
  if (datasets.length === 0) return h('p', {class: 'muted', id: 'datasets-empty'}, 'No datasets yet: upload a CSV or MAT file above.');
  return h('table', {class: 'wide', id: 'datasets'},
    h('thead', {}, h('tr', {}, ['Name', 'Samples', 'Inputs', 'Outputs', 't (s)', 'Size', 'Uploaded', ''].map((c) => h('th', {}, c)))),
    h('tbody', {}, datasets.map((d) => h('tr', {'data-id': d.id},
      h('td', {class: 'name'}, h('a', {href: '#/datasets/' + encodeURIComponent(d.id)}, d.name)),
      h('td', {class: 'num'}, num(d.samples)),
      h('td', {}, (d.inputNames || []).join(', ')),
      h('td', {}, (d.outputNames || []).join(', ')),
      h('td', {class: 'num'}, `${fmt(d.tStart)} – ${fmt(d.tEnd)}`),
      h('td', {class: 'num'}, `${fmt(num(d.sizeBytes) / 1024, 3)} kB`),
      h('td', {}, when(d.created)),
      h('td', {},
        h('a', {class: 'button', href: `#/identify?dataset=${encodeURIComponent(d.id)}`}, 'Identify'), ' ',
        h('button', {class: 'danger', onclick: async () => {
          if (!confirm(`Delete the dataset ${d.name}?`)) return;
          await api('DELETE', '/datasets/' + encodeURIComponent(d.id));
          await refresh();
        }}, 'Delete'))))));
}

function uploadForm(models, refresh) {
  const file = h('input', {type: 'file', id: 'upload-file', accept: '.csv,.mat,text/csv'});
  const name = h('input', {id: 'upload-name', placeholder: 'the file name'});
  const time = h('input', {id: 'upload-time', value: 't', size: 6});
  const inputs = h('input', {id: 'upload-inputs', placeholder: 'F1,F2', size: 18});
  const outputs = h('input', {id: 'upload-outputs', placeholder: 'h1,h2', size: 18});
  const truth = h('input', {id: 'upload-truth', placeholder: 'A1:10,A2:5 (optional)', size: 24});
  const model = h('select', {id: 'upload-model'}, h('option', {value: ''}, '(none)'),
    models.map((m) => h('option', {value: m.name}, m.name)));
  const columns = h('div', {class: 'chips muted', id: 'upload-columns'});
  const status = h('p', {id: 'upload-status'});
  const drop = h('div', {class: 'drop', id: 'upload-drop'}, 'Drop a CSV or MAT file here, or choose one: ', file);

  // The model's input and output names proposed as the columns.
  model.addEventListener('change', () => {
    const m = models.find((x) => x.name === model.value);
    if (!m) return;
    inputs.value = (m.inputNames || []).join(',');
    outputs.value = (m.outputNames || []).join(',');
  });
  const chosen = async (f) => {
    if (!f) return;
    if (!name.value) name.value = f.name;
    clear(columns);
    if (!f.name.toLowerCase().endsWith('.mat')) {
      const head = (await f.slice(0, 4096).text()).split(/\r?\n/)[0] || '';
      clear(columns, 'Columns: ', head.split(',').map((c) => h('span', {}, c.trim())));
    }
  };
  file.addEventListener('change', () => chosen(file.files[0]));
  drop.addEventListener('dragover', (e) => { e.preventDefault(); drop.classList.add('over'); });
  drop.addEventListener('dragleave', () => drop.classList.remove('over'));
  drop.addEventListener('drop', (e) => {
    e.preventDefault();
    drop.classList.remove('over');
    if (e.dataTransfer.files.length) { file.files = e.dataTransfer.files; chosen(file.files[0]); }
  });

  const submit = h('button', {class: 'primary', id: 'upload-button', type: 'submit'}, 'Upload');
  const form = h('form', {class: 'panel', id: 'upload'}, h('h2', {}, 'Upload'), drop, columns,
    h('div', {class: 'row'},
      h('label', {}, 'Name', name),
      h('label', {}, 'Propose columns of model', model),
      h('label', {}, 'Time column', time),
      h('label', {}, 'Input columns', inputs),
      h('label', {}, 'Output columns', outputs),
      h('label', {title: 'The parameters the data was made with, if known: results on it show each estimate\'s error'}, 'True parameters', truth),
      h('label', {}, '\u00a0', submit)),
    status);
  form.addEventListener('submit', async (e) => {
    e.preventDefault();
    const f = file.files[0];
    if (!f) return clear(status, errorBox('Choose a file first.'));
    const query = new URLSearchParams({
      name: name.value || f.name,
      format: f.name.toLowerCase().endsWith('.mat') ? 'mat' : 'csv',
      time_column: time.value, input_columns: inputs.value, output_columns: outputs.value,
    });
    if (truth.value.trim()) query.set('true_parameters', truth.value.replace(/\s+/g, ''));
    submit.disabled = true;
    clear(status, h('span', {class: 'muted'}, 'Uploading…'));
    try {
      const info = await api('POST', '/datasets?' + query, f, {raw: true});
      clear(status, h('span', {class: 'ok'}, `Stored ${info.name}: ${num(info.samples)} samples.`));
      await refresh();
    } catch (err) {
      clear(status, errorBox(err));
    } finally {
      submit.disabled = false;
    }
  });
  return form;
}

async function showOne(main, id, signal) {
  const data = await api('GET', `/datasets/${encodeURIComponent(id)}/data`, undefined, {signal});
  const info = data.info;
  const t = (data.t || []).map(num);
  const plots = h('div', {class: 'plots', id: 'signal-plots'});
  clear(main, h('h1', {}, 'Dataset ', h('span', {id: 'dataset-name'}, info.name)),
    h('p', {class: 'muted'}, `${num(info.samples)} samples from ${fmt(info.tStart)} s to ${fmt(info.tEnd)} s · `,
      h('a', {href: `#/identify?dataset=${encodeURIComponent(id)}`}, 'Identify with it'), ' · ',
      h('a', {href: `#/validate?dataset=${encodeURIComponent(id)}`}, 'Validate on it'), ' · ',
      h('a', {href: '#/datasets'}, 'All datasets')),
    Object.keys(info.trueParameters || {}).length === 0 ? null :
      h('p', {id: 'dataset-truth'}, 'True parameters: ', Object.entries(info.trueParameters).sort(([a], [b]) => a.localeCompare(b))
        .map(([n, v]) => `${n} = ${fmt(num(v), 6)}`).join(', ')),
    plots);
  (info.inputNames || []).forEach((n, i) => plot(plots, {title: `input ${n}`, x: t, series: [{label: n, values: row(data.u, i)}]}));
  (info.outputNames || []).forEach((n, i) => plot(plots, {title: `output ${n}`, x: t, series: [{label: n, values: row(data.y, i), color: '#d1242f'}]}));
}
