// What the page's own URL says (which log to open, the viewer token) and what the
// server put in the page (its settings: the map token).

/** The settings the server wrote into the page (see xviz_server/viewer.py). */
function serverSettings() {
  const element = document.getElementById('xviz-settings');
  return element ? JSON.parse(element.textContent) : {};
}

export function pageParams() {
  const query = new URLSearchParams(window.location.search);
  return {
    log: query.get('log'),
    token: query.get('token'),
    mapToken: serverSettings().mapToken || ''
  };
}

/** The page's URL that opens `log` (or the list, for null), keeping the viewer token. */
export function pageUrl(log, token) {
  const query = new URLSearchParams();
  if (log) {
    query.set('log', log);
  }
  if (token) {
    query.set('token', token);
  }
  const text = query.toString();
  return text ? `?${text}` : window.location.pathname;
}

/** The server's WebSocket address: the page's own host and port. */
export function serverUrl() {
  const scheme = window.location.protocol === 'https:' ? 'wss' : 'ws';
  return `${scheme}://${window.location.host}/`;
}

/** The catalog of logs and live feeds, from the server's JSON API. */
export async function fetchCatalog(token) {
  const url = token ? `/api/logs?token=${encodeURIComponent(token)}` : '/api/logs';
  let response;
  try {
    response = await fetch(url, {headers: {Accept: 'application/json'}});
  } catch (error) {
    throw new Error(`the server does not answer (${error.message})`);
  }
  if (!response.ok) {
    const text = (await response.text()).trim();
    throw new Error(`the server refused the catalog: ${response.status} ${text}`);
  }
  return response.json();
}
