// Seek in a log's file (opened by URL as a remote file) in the real Lichtblick web app in headless Chromium, and
// report how long the frame at the new time took to show and what the server sent meanwhile.
//
//   node tests/lichtblick-seek.mjs '{"url": "http://127.0.0.1:APP/?ds=remote-file&ds.url=...", "metrics": "http://...",
//                                    "panel": "RawMessages!seek", "until": ["sec: 1317042147", ...], "fraction": 0.5}'
//
// Once the app has opened the file and its reading has settled (the server's count of file bytes sent,
// xviz_file_bytes_sent_total on `metrics`, unchanged for a second; with `"settle": false`, as soon as the playback bar
// shows a time), it clicks the playback bar at `fraction` of
// its width, then reads the Raw Messages panel `panel` until its text holds every string of `until` (or the
// timeout, ms, default 60000). Prints one JSON object: "settledBytes" (sent before the click), "shownMs" (from
// the click to the text shown, or null), "clicked" (when it clicked, ms since the epoch), "seekBytes" (sent from the
// click until then), "texts" (the panel's texts
// after the click, in order), "time" (the app's playback time shown after the seek), "requests" (each request for the
// file the page made: its Range header, or null, and when, in ms from the click: negative before it), "drawn3d" (whether the 3D panel "3D!xviz", if the
// layout has one, showed a picture after the seek: looked at until it does, before the screenshot), "pageErrors",
// "externalRequests". Options: "screenshot" (a PNG of the page once the frame is shown and drawn).
import {drawn, launch, loopbackOnly, pixelTools} from './chromium.mjs';

const options = {timeout: 60000, fraction: 0.5, settle: true, ...JSON.parse(process.argv[2])};
const sent = async () => {
  const text = await (await fetch(options.metrics)).text();
  const line = text.split('\n').find(row => row.startsWith('xviz_file_bytes_sent_total '));
  return line ? Number(line.split(' ')[1]) : 0;
};
const sleep = ms => new Promise(resolve => setTimeout(resolve, ms));

const browser = await launch();
const report = {settledBytes: null, shownMs: null, clicked: null, seekBytes: null, texts: [], time: null, requests: [], drawn3d: null,
  pageErrors: [], externalRequests: []};
const deadline = Date.now() + options.timeout;
try {
  const page = await browser.newPage({viewport: {width: 1400, height: 900}});
  page.on('pageerror', error => report.pageErrors.push(String(error)));
  await loopbackOnly(page, report.externalRequests);
  await pixelTools(page);
  let clicked = null;
  const file = new URL(new URL(options.url).searchParams.get('ds.url')).pathname;
  page.on('request', request => {
    if (new URL(request.url()).pathname === file) {
      report.requests.push({range: request.headers().range || null, at: Date.now()});
    }
  });
  await page.goto(options.url, {waitUntil: 'domcontentloaded', timeout: options.timeout});
  const bar = page.locator('[class*="scrubberWrapper"]').first();
  await bar.waitFor({timeout: options.timeout});
  const panel = page.locator(`[data-testid~="${options.panel}"]`).first();
  await panel.waitFor({timeout: options.timeout});
  // The app reads the file's index, then reads ahead: the seek is timed once that has settled, or (`settle` false)
  // as soon as the playback bar shows a time (the app has read the file's summary), while it is still reading.
  const time = page.locator('[data-testid="PlaybackTime-text"] input, input[data-testid="PlaybackTime-text"]').first();
  let before = await sent();
  if (!options.settle) {
    while (Date.now() < deadline && !/\d{4}-\d\d-\d\d/.test(await time.inputValue({timeout: 1000}).catch(() => ''))) {
      await sleep(10);
    }
    before = await sent();
  } else {
    for (let still = 0; still < 1000 && Date.now() < deadline; ) {
      await sleep(100);
      const now = await sent();
      still = now === before ? still + 100 : 0;
      before = now;
    }
  }
  report.settledBytes = before;
  const box = await bar.boundingBox();
  clicked = Date.now();
  await page.mouse.click(box.x + box.width * options.fraction, box.y + box.height / 2);
  while (Date.now() < deadline) {
    const text = (await panel.innerText().catch(() => '')).replace(/\s+/g, ' ').trim();
    if (text && report.texts[report.texts.length - 1] !== text) report.texts.push(text);
    if (options.until.every(want => text.includes(want))) {
      report.shownMs = Date.now() - clicked;
      break;
    }
    await sleep(10);
  }
  report.seekBytes = (await sent()) - before;
  report.clicked = clicked;
  for (const request of report.requests) request.at -= clicked;
  if (await page.locator('[data-testid~="3D!xviz"]').count()) {
    report.drawn3d = await drawn(page, '3D!xviz', Math.max(deadline, Date.now() + 10000));
  }
  if (options.screenshot) await page.screenshot({path: options.screenshot});
  report.time = await time.inputValue().catch(() => null);
} catch (error) {
  report.pageErrors.push(`driver: ${error && error.stack || error}`);
} finally {
  await browser.close();
}
process.stdout.write(JSON.stringify(report));
