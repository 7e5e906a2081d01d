// Read a URL of this server from a page of another origin in headless Chromium, as the Foxglove and
// Lichtblick web apps read a remote file: one GET cut short once its head is in (its size, ETag and
// Accept-Ranges), then GETs of byte ranges.
//
//   node tests/cross-origin.mjs '{"url": "http://127.0.0.1:PORT/api/logs/NAME/file.mcap", "ranges": [[0, 99]]}'
//
// The page is served by the script itself on another loopback port (another origin; Chromium asks the
// user before a page of a public origin reaches a loopback address). Prints one JSON object:
// "open" {status, acceptRanges, contentLength, etag} or {error}; "ranges" [{status, contentRange, bytes}
// or {error}] for each [first, last] asked; "ifRange": the same for the first range asked with an If-Range
// (not a CORS-safelisted header: the browser asks the server first, with OPTIONS).
import {createServer} from 'node:http';
import {createRequire} from 'node:module';

const require = createRequire(new URL('../viewer/package.json', import.meta.url));
const {chromium} = require('playwright-core');

const options = JSON.parse(process.argv[2]);
const app = createServer((request, response) => {
  response.writeHead(200, {'Content-Type': 'text/html'});
  response.end('<!doctype html><title>app</title>');
});
await new Promise(resolve => app.listen(0, '127.0.0.1', resolve));
const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM || '/usr/bin/chromium',
  headless: true,
  args: ['--no-sandbox', '--disable-background-networking', '--disable-component-update', '--no-first-run']
});
try {
  const page = await browser.newPage();
  await page.goto(`http://127.0.0.1:${app.address().port}/`);
  const report = await page.evaluate(async ({url, ranges}) => {
    const attempt = async job => {
      try {
        return await job();
      } catch (error) {
        return {error: String(error)};
      }
    };
    const ranged = async (first, last, headers = {}) => {
      const response = await fetch(url, {headers: {range: `bytes=${first}-${last}`, ...headers}, cache: 'no-store'});
      const body = new Uint8Array(await response.arrayBuffer());
      return {status: response.status, contentRange: response.headers.get('content-range'), bytes: body.length};
    };
    const open = await attempt(async () => {
      const controller = new AbortController();
      const response = await fetch(url, {signal: controller.signal, cache: 'no-store'});
      controller.abort();
      return {
        status: response.status,
        acceptRanges: response.headers.get('accept-ranges'),
        contentLength: response.headers.get('content-length'),
        etag: response.headers.get('etag')
      };
    });
    const read = [];
    for (const [first, last] of ranges) {
      read.push(await attempt(() => ranged(first, last)));
    }
    const ifRange = await attempt(() => ranged(ranges[0][0], ranges[0][1], {'if-range': open.etag || '"none"'}));
    return {open, ranges: read, ifRange};
  }, options);
  process.stdout.write(JSON.stringify(report));
} finally {
  await browser.close();
  app.close();
}
