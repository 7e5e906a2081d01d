// Drive the viewer page in headless Chromium and report what a person would see.
//
//   node tests/browser.mjs '{"url": "http://127.0.0.1:PORT/?log=NAME", "screenshot": "out.png"}'
//
// Options: url; screenshot (PNG path); click (a log name to click in the catalog
// first); frames (WebSocket frames to wait for, default 3); timeout (ms, default
// 30000); settle (ms to wait before the report, default 1000); viewport ({width,
// height}, default 1280x800); draw (false: only load the page, wait for nothing). Prints one JSON object: frames received over the page's WebSockets,
// whether and when (ms after navigation) the 3D canvas first showed a picture, the
// canvas box in the screenshot, the stream list's text, the error banners, the page
// errors and console errors, and the catalog's text when one was shown.
// Each run launches a browser with a fresh profile of its own (playwright's).
import {createRequire} from 'node:module';

const require = createRequire(new URL('../viewer/package.json', import.meta.url));
const {chromium} = require('playwright-core');

const options = {frames: 3, timeout: 30000, draw: true, viewport: {width: 1280, height: 800}, ...JSON.parse(process.argv[2])};
const CANVAS = '#deckgl-overlay';
// A blank canvas is one flat colour; a drawn one (car, points, grid) varies.
const DRAWN_STDDEV = 4;

const browser = await chromium.launch({
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
const report = {failedRequests: [], drawn: false, firstDrawnMs: null, pageErrors: [], consoleErrors: [], alerts: []};
try {
  const page = await browser.newPage({viewport: options.viewport});
  const start = Date.now();
  page.on('pageerror', error => report.pageErrors.push(String(error)));
  page.on('console', message => {
    if (message.type() === 'error') {
      report.consoleErrors.push(message.text());
    }
  });
  page.on('response', response => {
    if (response.status() >= 400) {
      report.failedRequests.push(`${response.status()} ${response.url()}`);
    }
  });
  // Count the messages the page's WebSockets receive from inside the page: playwright's
  // own WebSocket events would copy every frame's payload to this process.
  await page.addInitScript(() => {
    window.__xvizMessages = {count: 0, first: null};
    const NativeWebSocket = window.WebSocket;
    window.WebSocket = class extends NativeWebSocket {
      constructor(...args) {
        super(...args);
        this.addEventListener('message', () => {
          window.__xvizMessages.count++;
          window.__xvizMessages.first = window.__xvizMessages.first ?? performance.timeOrigin + performance.now();
        });
      }
    };
  });
  const messages = () => page.evaluate(() => window.__xvizMessages);
  await page.goto(options.url);
  report.loadedMs = Date.now() - start;
  if (options.click) {
    const link = page.locator(`tr.log[data-log="${options.click}"] a`);
    await link.waitFor({timeout: options.timeout});
    report.catalogText = await page.locator('table.catalog').innerText();
    await link.click();
  }
  const deadline = options.draw ? start + options.timeout : start;
  while (Date.now() < deadline) {
    if ((await page.locator(CANVAS).count()) > 0 && (await messages()).count >= options.frames) {
      const png = await page.locator(CANVAS).screenshot();
      const stddev = await page.evaluate(pixelStddev, png.toString('base64'));
      if (stddev > DRAWN_STDDEV) {
        report.drawn = true;
        report.firstDrawnMs = Date.now() - start;
        break;
      }
    }
    if ((await page.locator('[role=alert]').count()) > 0 && !options.click) {
      break;
    }
    await page.waitForTimeout(50);
  }
  // Let the stream list and a few more frames arrive before the picture is kept.
  await page.waitForTimeout(options.settle ?? 1000);
  const received = await messages();
  report.frames = received.count;
  report.firstFrameMs = received.first === null ? null : Math.round(received.first - start);
  report.alerts = await page.locator('[role=alert]').allInnerTexts();
  const streams = page.locator('section.streams');
  report.streamsText = (await streams.count()) > 0 ? await streams.innerText() : '';
  report.canvasBox = (await page.locator(CANVAS).count()) > 0 ? await page.locator(CANVAS).boundingBox() : null;
  report.url = page.url();
  if (options.screenshot) {
    await page.screenshot({path: options.screenshot});
  }
} finally {
  await browser.close();
}
console.log(JSON.stringify(report));

/** In the page: the standard deviation of the grey levels of a base64 PNG. */
async function pixelStddev(base64) {
  const bytes = Uint8Array.from(atob(base64), c => c.charCodeAt(0));
  const bitmap = await createImageBitmap(new Blob([bytes], {type: 'image/png'}));
  const canvas = new OffscreenCanvas(bitmap.width, bitmap.height);
  const context = canvas.getContext('2d');
  context.drawImage(bitmap, 0, 0);
  const {data} = context.getImageData(0, 0, bitmap.width, bitmap.height);
  let sum = 0;
  let sumSquares = 0;
  const count = data.length / 4;
  for (let i = 0; i < data.length; i += 4) {
    const grey = (data[i] + data[i + 1] + data[i + 2]) / 3;
    sum += grey;
    sumSquares += grey * grey;
  }
  const mean = sum / count;
  return Math.sqrt(Math.max(0, sumSquares / count - mean * mean));
}
