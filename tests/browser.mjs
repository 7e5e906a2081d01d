// Drive the viewer page in headless Chromium and report what a person would see.
//
//   node tests/browser.mjs '{"url": "http://127.0.0.1:PORT/?log=NAME", "screenshot": "out.png"}'
//
// Options: url; screenshot (PNG path); search (text to type in the catalog's search
// box, then wait for the list to change); more (times to click "More logs" after it);
// click (a log name to click in the catalog first); frames (WebSocket frames to wait for, default 3); timeout (ms, default
// 30000); settle (ms to wait before the report, default 1000); viewport ({width,
// height}, default 1280x800); draw (false: only load the page, wait for nothing);
// reload (true: reload the page once its address holds no token, then go on);
// seek (once drawn, click the timeline at this fraction of its width, then wait for
// the next message and for the 3D view to show a changed picture); detail (once drawn,
// pick this level of detail in the header's list and wait for the page to show it in use);
// hosts (more host names, besides this machine's loopback ones, that the page may reach);
// foxglove (a log name: read the Foxglove URL its catalog row shows, click its Copy button and
// read the clipboard, the row's link to Foxglove's web app, and its links to the log's file and to the app opening it).
// Prints one JSON object: frames received over the page's WebSockets, whether and
// when (ms after navigation, as the screenshot was taken) the 3D canvas first showed a
// picture, the page's own timings (ms after navigation: the script bundle received, and the User Timing
// marks of viewer/src/timing.js), the bundle's files it loaded (bytes sent, as the
// server compressed them, and their size), the canvas box in the screenshot, the stream list's
// text, the error banners, the page errors and console errors, the catalog's text
// when one was shown, the requests to hosts other than this machine (each refused:
// the tests use no network), after a seek what the playback control shows, the
// page's address at the end, the URLs of its WebSockets, what its
// Content-Security-Policy refused, the catalog's rows and count after a search,
// and the link the page offers to the time shown; with foxglove, the row's Foxglove URL,
// what its Copy button put on the clipboard, its link to Foxglove's web app, its file's URL
// and the app's link opening that file.
// Each run launches a browser with a fresh profile of its own (playwright's).
//
// The canvas is screenshotted (which makes the browser composite a frame, and on a
// software renderer costs time) only once the page has a frame to draw: the mark
// "xviz:first-frame"; what the screenshot shows is what a person would see then.
import {createRequire} from 'node:module';

const require = createRequire(new URL('../viewer/package.json', import.meta.url));
const {chromium} = require('playwright-core');

const options = {frames: 3, timeout: 30000, draw: true, viewport: {width: 1280, height: 800}, ...JSON.parse(process.argv[2])};
const CANVAS = '#deckgl-overlay';
// A blank canvas is one flat colour; a drawn one (car, points, grid) varies.
const DRAWN_STDDEV = 4;
// A changed picture differs from the one before by this mean grey level, or more.
const CHANGED = 2;

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
const report = {
  failedRequests: [],
  externalRequests: [],
  drawn: false,
  firstDrawnMs: null,
  pageErrors: [],
  consoleErrors: [],
  alerts: []
};
try {
  const page = await browser.newPage({viewport: options.viewport});
  if (options.foxglove !== undefined) {
    await page.context().grantPermissions(['clipboard-read', 'clipboard-write']);
  }
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
  const local = ['127.0.0.1', 'localhost', '[::1]', ...(options.hosts || [])];
  await page.route(
    url => !local.includes(url.hostname) && url.protocol !== 'data:',
    route => {
      report.externalRequests.push(route.request().url());
      return route.abort('blockedbyclient');
    }
  );
  // Count the messages the page's WebSockets receive from inside the page: playwright's
  // own WebSocket events would copy every frame's payload to this process.
  await page.addInitScript(() => {
    // Whatever the page's Content-Security-Policy refused, as the browser reports it to the page.
    window.__cspViolations = [];
    document.addEventListener('securitypolicyviolation', event =>
      window.__cspViolations.push(`${event.effectiveDirective} refused ${event.blockedURI || 'inline'} (${event.sourceFile}:${event.lineNumber})`)
    );
    window.__xvizMessages = {count: 0, first: null};
    const NativeWebSocket = window.WebSocket;
    window.__xvizSocketUrls = [];
    window.WebSocket = class extends NativeWebSocket {
      constructor(...args) {
        super(...args);
        window.__xvizSocketUrls.push(String(args[0]));
        this.addEventListener('message', () => {
          window.__xvizMessages.count++;
          window.__xvizMessages.first = window.__xvizMessages.first ?? performance.timeOrigin + performance.now();
        });
      }
    };
  });
  const messages = () => page.evaluate(() => window.__xvizMessages);
  const hasFrame = () => page.evaluate(() => performance.getEntriesByName('xviz:first-frame').length > 0);
  // The canvas's picture, and when it was taken (ms after navigation): the page's thread,
  // which pixelStats needs after it, may be busy with what came next.
  const canvasShot = async () => {
    const png = await page.locator(CANVAS).screenshot();
    const takenMs = Date.now() - start;
    return {takenMs, stddev: (await page.evaluate(pixelStats, [png.toString('base64')])).stddev};
  };
  await page.goto(options.url);
  if (options.reload) {
    // Once the page took what it needs from its address (the viewer token), as a person pressing F5.
    await page.waitForFunction(() => !window.location.search.includes('token='), null, {timeout: options.timeout});
    await page.reload();
  }
  report.loadedMs = Date.now() - start;
  if (options.search !== undefined || options.more) {
    await searchCatalog(page);
  }
  if (options.foxglove !== undefined) {
    const row = page.locator(`tr.log[data-log="${options.foxglove}"]`);
    await row.waitFor({timeout: options.timeout});
    report.foxgloveUrl = await row.locator('input.foxglove-url').inputValue();
    await row.locator('button.foxglove-copy').click();
    await row.locator('button.foxglove-copy', {hasText: 'Copied'}).waitFor({timeout: options.timeout});
    report.foxgloveCopied = await page.evaluate(() => navigator.clipboard.readText());
    report.foxgloveAppLink = await row.locator('a.foxglove-open').getAttribute('href');
    report.foxgloveFileLink = await row.locator('a.foxglove-file').getAttribute('href');
    report.foxgloveFileAppLink = await row.locator('a.foxglove-open-file').getAttribute('href');
    report.catalogText = await page.locator('table.catalog').innerText();
  }
  if (options.click) {
    const link = page.locator(`tr.log[data-log="${options.click}"] td:first-child a`);
    await link.waitFor({timeout: options.timeout});
    report.catalogText = await page.locator('table.catalog').innerText();
    await link.click();
  }
  const deadline = options.draw ? start + options.timeout : start;
  while (Date.now() < deadline) {
    if ((await page.locator(CANVAS).count()) > 0 && (await messages()).count >= options.frames && (await hasFrame())) {
      const shot = await canvasShot();
      if (shot.stddev > DRAWN_STDDEV) {
        report.drawn = true;
        report.firstDrawnMs = shot.takenMs;
        break;
      }
    }
    if ((await page.locator('[role=alert]').count()) > 0 && !options.click) {
      break;
    }
    await page.waitForTimeout(50);
  }
  report.marks = await page.evaluate(() => {
    const marks = {};
    const bundle = performance.getEntriesByType('resource').find(entry => /\/viewer-\w+\.js$/.test(entry.name));
    if (bundle) {
      marks.bundle = Math.round(bundle.responseEnd);
    }
    for (const mark of performance.getEntriesByType('mark').filter(entry => entry.name.startsWith('xviz:'))) {
      marks[mark.name.slice(5)] = Math.round(mark.startTime);
    }
    return marks;
  });
  report.assets = await page.evaluate(() =>
    performance
      .getEntriesByType('resource')
      .filter(entry => /\/viewer-\w+\.(js|css)$/.test(entry.name))
      .map(entry => ({name: entry.name.split('/').pop(), sent: entry.encodedBodySize, size: entry.decodedBodySize}))
  );
  if (options.seek !== undefined && report.drawn) {
    report.seek = await seek(page, options.seek);
  }
  if (options.detail !== undefined && report.drawn) {
    const shown = page.locator('.detail-level');
    await shown.waitFor({timeout: options.timeout});
    report.detailBefore = await shown.innerText();
    await page.locator('.detail select').selectOption(options.detail);
    await page.waitForFunction(
      level => document.querySelector('.detail-level').innerText.startsWith(level),
      options.detail,
      {timeout: options.timeout}
    );
    report.detailAfter = await shown.innerText();
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
  report.cspViolations = await page.evaluate(() => window.__cspViolations);
  report.socketUrls = await page.evaluate(() => window.__xvizSocketUrls);
  const playback = page.locator('.playback');
  report.playbackText = (await playback.count()) > 0 ? await playback.innerText() : '';
  const timeLink = page.locator('a.time-link');
  report.timeLink = (await timeLink.count()) > 0 ? await timeLink.getAttribute('href') : null;
  if (options.screenshot) {
    await page.screenshot({path: options.screenshot});
  }
} finally {
  await browser.close();
}
console.log(JSON.stringify(report));

/** Type `options.search` in the catalog's search box, then click "More logs" `options.more` times; report the rows. */
async function searchCatalog(page) {
  const rows = () => page.evaluate(() => [...document.querySelectorAll('tr.log')].map(row => row.dataset.log));
  await page.locator('table.catalog').waitFor({timeout: options.timeout});
  if (options.search !== undefined) {
    const before = JSON.stringify(await rows());
    await page.locator('input.catalog-search').fill(options.search);
    await page.waitForFunction(
      shown => JSON.stringify([...document.querySelectorAll('tr.log')].map(row => row.dataset.log)) !== shown,
      before,
      {timeout: options.timeout}
    );
  }
  for (let i = 0; i < (options.more || 0); i++) {
    const count = (await rows()).length;
    await page.locator('button.catalog-more').click();
    await page.waitForFunction(n => document.querySelectorAll('tr.log').length > n, count, {timeout: options.timeout});
  }
  report.catalogRows = await rows();
  report.catalogCount = await page.locator('.catalog-count').innerText();
  report.moreOffered = (await page.locator('button.catalog-more').count()) > 0;
}

/** Click the timeline at `fraction`; what the playback control shows before and after, and the pictures' difference. */
async function seek(page, fraction) {
  const before = await page.locator(CANVAS).screenshot();
  const shownBefore = await page.locator('.playback').innerText();
  const count = (await page.evaluate(() => window.__xvizMessages)).count;
  const slider = page.locator('.playback [tabindex="0"]').first();
  const box = await slider.boundingBox();
  await page.mouse.click(box.x + box.width * fraction, box.y + box.height / 2);
  await page.waitForFunction(n => window.__xvizMessages.count > n, count, {timeout: options.timeout});
  let changed = 0;
  for (const start = Date.now(); Date.now() - start < options.timeout && changed < CHANGED; ) {
    const after = await page.locator(CANVAS).screenshot();
    changed = (await page.evaluate(pixelStats, [before.toString('base64'), after.toString('base64')])).difference;
  }
  return {shownBefore, shownAfter: await page.locator('.playback').innerText(), pictureChange: changed};
}

/**
 * In the page, for base64 PNGs of one size: the standard deviation of the first's grey
 * levels, and the mean absolute difference of the second's from the first's.
 */
async function pixelStats(images) {
  const greys = [];
  for (const base64 of images) {
    const bytes = Uint8Array.from(atob(base64), c => c.charCodeAt(0));
    const bitmap = await createImageBitmap(new Blob([bytes], {type: 'image/png'}));
    const canvas = new OffscreenCanvas(bitmap.width, bitmap.height);
    const context = canvas.getContext('2d');
    context.drawImage(bitmap, 0, 0);
    const {data} = context.getImageData(0, 0, bitmap.width, bitmap.height);
    const grey = new Float32Array(data.length / 4);
    for (let i = 0; i < grey.length; i++) {
      grey[i] = (data[4 * i] + data[4 * i + 1] + data[4 * i + 2]) / 3;
    }
    greys.push(grey);
  }
  const [first, second] = greys;
  let sum = 0;
  let sumSquares = 0;
  let difference = 0;
  for (let i = 0; i < first.length; i++) {
    sum += first[i];
    sumSquares += first[i] * first[i];
    difference += second ? Math.abs(second[i] - first[i]) : 0;
  }
  const mean = sum / first.length;
  return {stddev: Math.sqrt(Math.max(0, sumSquares / first.length - mean * mean)), difference: difference / first.length};
}
