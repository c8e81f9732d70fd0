// The workbench: a page per hash route (#/datasets, #/jobs/<id>, ...), so
// every view can be bookmarked and shared; sign-in with a bearer token.
import {api, setToken, token, whenUnauthorized} from './api.js';
import {clear, errorBox, h} from './dom.js';
import * as datasets from './pages/datasets.js';
import * as identify from './pages/identify.js';
import * as jobs from './pages/jobs.js';
import * as models from './pages/models.js';
import * as sessions from './pages/sessions.js';
import * as validate from './pages/validate.js';

const kPages = [
  ['datasets', 'Datasets', datasets],
  ['identify', 'Identify', identify],
  ['validate', 'Validate', validate],
  ['sessions', 'Sessions', sessions],
  ['models', 'Models', models],
  ['jobs', 'Jobs', jobs],
];

const main = document.getElementById('main');
const kNoToken = '-';  // what is sent to a riccatid that asks for none
let current = null;  // the page's AbortController: its streams and timers end when it is left

// "#/jobs/abc?x=1" -> {page: 'jobs', id: 'abc', query: URLSearchParams}
function route() {
  const hash = location.hash.replace(/^#\/?/, '');
  const [path, query] = hash.split('?');
  const [page, ...rest] = path.split('/');
  return {page: page || 'datasets', id: rest.map(decodeURIComponent).join('/'), query: new URLSearchParams(query || '')};
}

function signIn(message) {
  if (current) current.abort();
  clear(document.getElementById('nav'));
  clear(document.getElementById('account'));
  const input = h('input', {type: 'password', id: 'token', placeholder: 'bearer token', autocomplete: 'off'});
  const status = h('p', {class: 'error', id: 'signin-error'}, message || '');
  const form = h('form', {class: 'panel signin', id: 'signin'},
    h('h1', {}, 'Sign in to riccatid'),
    h('p', {class: 'muted'}, 'Your token (riccati\'s tokens file holds its digest). It stays in this tab only.'),
    input, h('p', {}, h('button', {class: 'primary', type: 'submit', id: 'signin-button'}, 'Sign in')), status);
  form.addEventListener('submit', async (e) => {
    e.preventDefault();
    setToken(input.value.trim());
    try {
      await api('GET', '/models');
      render();
    } catch (err) {
      setToken('');
      clear(status, String(err.message));
    }
  });
  clear(main, form);
  input.focus();
}

whenUnauthorized((message) => { setToken(''); signIn(message); });

async function render() {
  if (!token()) {
    // Without a tokens file riccatid lets loopback in as tenant "default": try first.
    try {
      setToken(kNoToken);
      await api('GET', '/models');
    } catch (_) {
      setToken('');
      return signIn();
    }
  }
  const r = route();
  const nav = document.getElementById('nav');
  clear(nav, kPages.map(([key, title]) => h('a', {href: '#/' + key, class: key === r.page ? 'active' : ''}, title)));
  // Signed in with a token: it can be signed out. Let in without one (a
  // riccatid without a tokens file, on loopback): nothing to sign out of.
  clear(document.getElementById('account'), token() === kNoToken ? h('span', {class: 'muted', id: 'no-token'}, 'no sign-in needed') :
    h('button', {id: 'signout', onclick: () => { setToken(''); signIn(); }}, 'Sign out'));
  if (current) current.abort();
  current = new AbortController();
  const entry = kPages.find(([key]) => key === r.page);
  if (!entry) return clear(main, h('h1', {}, 'No such page'), h('p', {}, h('a', {href: '#/datasets'}, 'Datasets')));
  document.title = `${entry[1]} · riccati`;
  clear(main, h('p', {class: 'muted'}, 'Loading…'));
  try {
    await entry[2].show(main, r, current.signal);
  } catch (err) {
    if (err.name !== 'AbortError') main.append(errorBox(err));
  }
}

window.addEventListener('hashchange', render);
render();
