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

// Give `page` (before it loads) the pixel tools the drivers count with, run by the page's own image decoder:
// window.countColour(base64 PNG, '#rrggbb'): the pixels of that colour (within 40 per channel);
// window.colours(base64 PNG): how many colours it shows (one pixel in 97 looked at; a flat or empty view shows a few).
export function pixelTools(page) {
  return page.addInitScript(() => {
    const pixelsOf = async base64 => {
      const image = new Image();
      image.src = `data:image/png;base64,${base64}`;
      await image.decode();
      const canvas = new OffscreenCanvas(image.width, image.height);
      const context = canvas.getContext('2d');
      context.drawImage(image, 0, 0);
      return context.getImageData(0, 0, image.width, image.height).data;
    };
    window.countColour = async (base64, hex) => {
      const data = await pixelsOf(base64);
      const want = [1, 3, 5].map(i => parseInt(hex.slice(i, i + 2), 16));
      let count = 0;
      for (let i = 0; i < data.length; i += 4) {
        if (Math.abs(data[i] - want[0]) < 40 && Math.abs(data[i + 1] - want[1]) < 40 && Math.abs(data[i + 2] - want[2]) < 40) count++;
      }
      return count;
    };
    window.colours = async base64 => {
      const data = await pixelsOf(base64);
      const seen = new Set();
      for (let i = 0; i < data.length; i += 4 * 97) seen.add((data[i] << 16) | (data[i + 1] << 8) | data[i + 2]);
      return seen.size;
    };
  });
}

// Whether the canvas of the panel `id` (a Lichtblick panel's data-testid) shows a picture (over 20 colours),
// looked at until it does or `deadline` (ms since the epoch): a screenshot taken before the app has drawn is blank.
export async function drawn(page, id, deadline) {
  const canvas = page.locator(`[data-testid~="${id}"] canvas`).first();
  do {
    const shot = await canvas.screenshot({timeout: 1000}).catch(() => null);
    if (shot && await page.evaluate(base64 => window.colours(base64), shot.toString('base64')) > 20) return true;
    await new Promise(resolve => setTimeout(resolve, 100));
  } while (Date.now() < deadline);
  return false;
}
