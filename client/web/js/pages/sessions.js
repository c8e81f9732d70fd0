// Sessions: the tenant's filter sessions, and one session live
// (#/sessions/<id>): states and parameters with ±2σ bands as measurements
// arrive (riccatid sends at most 10 estimates a second).
import {api, events} from '../api.js';
import {clear, enumName, errorBox, fmt, h, num, when} from '../dom.js';
import {plot, setData} from '../plot.js';

const kKeep = 3000;  // points per plot

export async function show(main, r, signal) {
  if (r.id) return showOne(main, r.id, signal);
  const draw = async () => {
    const sessions = (await api('GET', '/sessions', undefined, {signal})).sessions || [];
    clear(main, h('h1', {}, 'Sessions'),
      h('p', {class: 'muted'}, 'Filter sessions that rigs stream measurements into (riccati stream, or the API\'s Stream).'),
      sessions.length === 0 ? h('p', {class: 'muted', id: 'sessions-empty'}, 'No sessions open.') :
        h('table', {class: 'wide', id: 'sessions'},
          h('thead', {}, h('tr', {}, ['Session', 'Model', 'Filter', 'State', 'Measurements', 't (s)', 'Last active', ''].map((c) => h('th', {}, c)))),
          h('tbody', {}, sessions.map((s) => {
            const state = enumName(s.state, 'SESSION_STATE_');
            return h('tr', {'data-id': s.id},
              h('td', {}, h('a', {href: '#/sessions/' + encodeURIComponent(s.id)}, s.id)),
              h('td', {}, s.model), h('td', {}, enumName(s.filter, 'FILTER_KIND_')),
              h('td', {class: 'state ' + state}, state), h('td', {class: 'num'}, num(s.measurements)),
              h('td', {class: 'num'}, fmt(s.t)), h('td', {}, when(s.lastActive)),
              h('td', {}, h('button', {class: 'danger', onclick: async () => {
                if (!confirm(`Close the session ${s.id}?`)) return;
                await api('DELETE', '/sessions/' + encodeURIComponent(s.id));
                draw();
              }}, 'Close')));
          }))));
  };
  await draw();
  const timer = setInterval(() => draw().catch(() => {}), 3000);
  signal.addEventListener('abort', () => clearInterval(timer));
}

async function showOne(main, id, signal) {
  const info = await api('GET', '/sessions/' + encodeURIComponent(id), undefined, {signal});
  const model = await api('GET', '/models/' + encodeURIComponent(info.model), undefined, {signal});
  const names = [...(model.stateNames || []), ...(model.paramNames || [])];
  const summary = h('p', {id: 'session-summary'});
  const retunings = h('div', {id: 'retunings'});
  const drawRetunings = (list) => clear(retunings, (list || []).length === 0 ? null : h('table', {},
    h('thead', {}, h('tr', {}, ['Retuned at t (s)', 'After measurements', 'Q', 'R', 'V', 'W'].map((c) => h('th', {}, c)))),
    h('tbody', {}, list.map((r) => h('tr', {}, h('td', {class: 'num'}, fmt(r.t)), h('td', {class: 'num'}, num(r.measurements)),
      [r.q, r.r, r.v, r.w].map((c) => h('td', {}, covarianceText(c))))))));
  const values = h('tbody');
  const plots = h('div', {class: 'plots', id: 'session-plots'});
  clear(main, h('h1', {}, 'Session ', h('span', {}, id)),
    h('p', {class: 'muted'}, `${info.model} · ${enumName(info.filter, 'FILTER_KIND_')} · `, h('a', {href: '#/sessions'}, 'all sessions')),
    summary,
    retuneForm(id, info, model, drawRetunings), retunings,
    h('table', {id: 'session-values'}, h('thead', {}, h('tr', {}, ['', 'Estimate', '±2σ'].map((c) => h('th', {class: 'num'}, c)))), values),
    plots);
  const t = [], z = names.map(() => []), s = names.map(() => []);
  const boxes = names.map((n) => plot(plots, {title: n, x: [], width: 420, height: 200, bands: [[2, 3]], series: [
    {label: n, values: [], color: '#1f6feb'},
    {label: '+2σ', values: [], color: 'rgba(31,111,235,.35)', width: 1},
    {label: '−2σ', values: [], color: 'rgba(31,111,235,.35)', width: 1}]}));
  drawRetunings(info.retunings);
  let shownRetunings = (info.retunings || []).length;
  const update = ({info: i, estimate: e}) => {
    if ((i.retunings || []).length !== shownRetunings) { shownRetunings = (i.retunings || []).length; drawRetunings(i.retunings); }
    const state = enumName(i.state, 'SESSION_STATE_');
    clear(summary, h('span', {class: 'state ' + state, id: 'session-state'}, state),
      ` · ${num(i.measurements)} measurements · t = ${fmt(i.t)} s`,
      i.error && i.error.message ? errorBox(i.error.message) : null);
    if (!e) return;
    t.push(num(e.t));
    names.forEach((_, k) => { z[k].push(num(e.state[k])); s[k].push(num(e.std[k])); });
    if (t.length > kKeep) { t.shift(); z.forEach((a) => a.shift()); s.forEach((a) => a.shift()); }
    clear(values, names.map((n, k) => h('tr', {}, h('th', {}, n), h('td', {class: 'num'}, fmt(e.state[k], 5)), h('td', {class: 'num'}, fmt(2 * num(e.std[k]), 3)))));
    boxes.forEach((box, k) => setData(box, t, [z[k], z[k].map((v, j) => v + 2 * s[k][j]), z[k].map((v, j) => v - 2 * s[k][j])]));
  };
  await events(`/sessions/${encodeURIComponent(id)}/events`, (name, data) => {
    if (name === 'session') update(data);
    if (name === 'error') summary.append(errorBox(data.message));
  }, signal);
}

function covarianceText(c) {
  if (!c) return '';
  if (c.diagonal) return `diag(${(c.diagonal.values || []).map((v) => fmt(v)).join(', ')})`;
  if (c.scalar !== undefined) return `${fmt(c.scalar)} I`;
  if (c.full) return `${num(c.full.rows)} x ${num(c.full.cols)} matrix`;
  return '';
}

// Live retuning: new noise weights between two measurements (the EKF's and
// UKF's R by output and Q by state and parameter; the optimal filter's V and
// W as diagonals), recorded in the session's history.
function retuneForm(id, info, model, drawRetunings) {
  const optimal = info.filter === 'FILTER_KIND_OPTIMAL';
  const outputs = model.outputNames || [], nz = [...(model.stateNames || []), ...(model.paramNames || [])];
  const status = h('span', {id: 'retune-status'});
  const input = (key) => h('input', {type: 'number', step: 'any', id: key, placeholder: 'unchanged'});
  const fields = optimal
    ? [h('label', {}, 'V (diagonal, comma-separated)', h('input', {id: 'retune-v', size: 30, placeholder: 'unchanged'})),
       h('label', {}, 'W (diagonal, comma-separated)', h('input', {id: 'retune-w', size: 30, placeholder: 'unchanged'}))]
    : [outputs.map((y) => h('label', {}, `R of ${y}`, input('retune-r-' + y))),
       nz.map((n) => h('label', {}, `Q of ${n}`, input('retune-q-' + n)))];
  const form = h('form', {class: 'panel', id: 'retune'}, h('h3', {}, 'Retune the filter while it runs'),
    h('div', {class: 'row'}, fields, h('label', {}, '\u00a0', h('button', {class: 'primary', id: 'retune-apply', type: 'submit'}, 'Apply'))),
    status);
  const diag = (values) => ({diagonal: {values}});
  const list = (text) => text.split(',').map((v) => v.trim()).filter((v) => v !== '').map(Number);
  form.addEventListener('submit', async (e) => {
    e.preventDefault();
    const request = {};
    if (optimal) {
      const v = list(document.getElementById('retune-v').value), w = list(document.getElementById('retune-w').value);
      if (v.length) request.v = diag(v);
      if (w.length) request.w = diag(w);
    } else {
      // A weight left empty keeps its value: R and Q go whole, so empty ones need theirs.
      const r = outputs.map((y) => document.getElementById('retune-r-' + y).value.trim());
      const q = nz.map((n) => document.getElementById('retune-q-' + n).value.trim());
      if (r.some((v) => v !== '')) {
        if (r.some((v) => v === '')) return clear(status, errorBox('Give R for every output.'));
        request.r = diag(r.map(Number));
      }
      if (q.some((v) => v !== '')) {
        if (q.some((v) => v === '')) return clear(status, errorBox('Give Q for every state and parameter.'));
        request.q = diag(q.map(Number));
      }
    }
    try {
      const updated = await api('POST', `/sessions/${encodeURIComponent(id)}/retune`, request);
      clear(status, h('span', {class: 'ok'}, `Retuned at t = ${fmt(updated.t)} s.`));
      drawRetunings(updated.retunings);
    } catch (err) {
      clear(status, errorBox(err));
    }
  });
  return form;
}
