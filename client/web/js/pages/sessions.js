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

// A covariance as the API gives it (diagonal, full or scalar) as an n x n
// column-major array; null when absent.
function fullOf(c, n) {
  if (!c) return null;
  const m = new Array(n * n).fill(0);
  if (c.full) (c.full.values || []).forEach((v, k) => { m[k] = num(v); });
  else if (c.diagonal) (c.diagonal.values || []).forEach((v, k) => { if (k < n) m[k + k * n] = num(v); });
  else if (c.scalar !== undefined) for (let k = 0; k < n; ++k) m[k + k * n] = num(c.scalar);
  else return null;
  return m;
}

const isDiagonal = (m, n) => m.every((v, k) => v === 0 || k % n === Math.floor(k / n));

// Live retuning: new noise weights between two measurements (the EKF's and
// UKF's R by output and Q by state and parameter; the optimal filter's V and
// W diagonals), each field showing what the filter runs with now
// (SessionInfo's q, r, v, w). Only what was changed is sent: R or Q whole,
// the off-diagonal entries of a full one kept.
function retuneForm(id, info, model, drawRetunings) {
  const optimal = info.filter === 'FILTER_KIND_OPTIMAL';
  const outputs = model.outputNames || [], nz = [...(model.stateNames || []), ...(model.paramNames || [])];
  const status = h('span', {id: 'retune-status'});
  // key -> {names (one field each), current (n x n), fields}
  const weights = optimal
    ? {v: {title: 'V', names: null}, w: {title: 'W', names: nz}}
    : {r: {title: 'R', names: outputs}, q: {title: 'Q', names: nz}};
  const setCurrent = (from) => {
    for (const [key, wt] of Object.entries(weights)) {
      const c = from[key];
      const n = wt.names ? wt.names.length : (c && c.diagonal ? (c.diagonal.values || []).length : c && c.full ? num(c.full.rows) : 0);
      wt.n = n;
      wt.current = fullOf(c, n);
      (wt.fields || []).forEach((field, k) => {
        field.value = wt.current ? String(wt.current[k + k * n]) : '';
        field.placeholder = wt.current ? '' : 'unchanged';
      });
    }
  };
  const fields = [];
  for (const [key, wt] of Object.entries(weights)) {
    const c = info[key];
    const n = wt.names ? wt.names.length : (c && c.diagonal ? (c.diagonal.values || []).length : c && c.full ? num(c.full.rows) : 0);
    const labels = wt.names || Array.from({length: n}, (_, k) => String(k + 1));
    wt.fields = labels.map((name) => h('input', {type: 'number', step: 'any', id: `retune-${key}-${name}`, size: 9}));
    fields.push(h('fieldset', {class: 'row', id: `retune-${key}`}, h('legend', {}, `${wt.title} (diagonal; now)`),
      wt.fields.map((field, k) => h('label', {}, `${wt.title} of ${labels[k]}`, field))));
  }
  setCurrent(info);
  const form = h('form', {class: 'panel', id: 'retune'}, h('h3', {}, 'Retune the filter while it runs'),
    h('div', {class: 'row'}, fields, h('label', {}, '\u00a0', h('button', {class: 'primary', id: 'retune-apply', type: 'submit'}, 'Apply'))),
    status);
  form.addEventListener('submit', async (e) => {
    e.preventDefault();
    const request = {};
    for (const [key, wt] of Object.entries(weights)) {
      const n = wt.fields.length;
      const typed = wt.fields.map((f) => f.value.trim());
      const bad = typed.findIndex((v) => v !== '' && !Number.isFinite(Number(v)));
      if (bad >= 0) return clear(status, errorBox(`${wt.title}: "${typed[bad]}" is not a number.`));
      if (!wt.current) {
        // Nothing known of it: all or none.
        if (typed.every((v) => v === '')) continue;
        if (typed.some((v) => v === '')) return clear(status, errorBox(`${wt.title}: give every value, or none.`));
        request[key] = {diagonal: {values: typed.map(Number)}};
        continue;
      }
      const next = wt.current.slice();
      typed.forEach((v, k) => { if (v !== '') next[k + k * n] = Number(v); });
      if (next.every((v, k) => v === wt.current[k])) continue;  // unchanged
      request[key] = isDiagonal(next, n) ? {diagonal: {values: Array.from({length: n}, (_, k) => next[k + k * n])}}
        : {full: {rows: n, cols: n, values: next}};
    }
    if (Object.keys(request).length === 0) return clear(status, h('span', {class: 'muted'}, 'Nothing changed.'));
    try {
      const updated = await api('POST', `/sessions/${encodeURIComponent(id)}/retune`, request);
      clear(status, h('span', {class: 'ok'}, `Retuned ${Object.keys(request).map((k) => weights[k].title).join(' and ')} at t = ${fmt(updated.t)} s.`));
      setCurrent(updated);
      drawRetunings(updated.retunings);
    } catch (err) {
      clear(status, errorBox(err));
    }
  });
  return form;
}
