// Debian's chromium, headless, as the browser tests launch it: software WebGL, no network of its own.
import {createRequire} from 'node:module';

const require = createRequire(new URL('../viewer/package.json', import.meta.url));
const {chromium} = require('playwright-core');

// Abort every request of `page` to a host other than this machine's loopback (or `hosts`), listing its origin in
// `refused`: the tests use no network.
export function loopbackOnly(page, refused, hosts = []) {
  const allowed = new Set(['127.0.0.1', 'localhost', '[::1]', ...hosts]);
  return page.route('**/*', route => {
    const url = new URL(route.request().url());
    if (['http:', 'https:', 'ws:', 'wss:'].includes(url.protocol) && !allowed.has(url.hostname)) {
      refused.push(url.origin);
      return route.abort();
    }
    return route.continue();
  });
}

export function launch() {
  return chromium.launch({
    executablePath: process.env.CHROMIUM || '/usr/bin/chromium',
    headless: true,
    args: [
      '--no-sandbox',
      '--use-angle=swiftshader',
      '--enable-unsafe-swiftshader',
      '--disable-background-networking',
      '--disable-component-update',
      '--disable-sync',
      '--no-first-run',
      '--disable-quic'
    ]
  });
}
