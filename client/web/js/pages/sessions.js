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
  const values = h('tbody');
  const plots = h('div', {class: 'plots', id: 'session-plots'});
  clear(main, h('h1', {}, 'Session ', h('span', {}, id)),
    h('p', {class: 'muted'}, `${info.model} · ${enumName(info.filter, 'FILTER_KIND_')} · `, h('a', {href: '#/sessions'}, 'all sessions')),
    summary,
    h('table', {id: 'session-values'}, h('thead', {}, h('tr', {}, ['', 'Estimate', '±2σ'].map((c) => h('th', {class: 'num'}, c)))), values),
    plots);
  const t = [], z = names.map(() => []), s = names.map(() => []);
  const boxes = names.map((n) => plot(plots, {title: n, x: [], width: 420, height: 200, bands: [[2, 3]], series: [
    {label: n, values: [], color: '#1f6feb'},
    {label: '+2σ', values: [], color: 'rgba(31,111,235,.35)', width: 1},
    {label: '−2σ', values: [], color: 'rgba(31,111,235,.35)', width: 1}]}));
  const update = ({info: i, estimate: e}) => {
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
