// Drive the real Lichtblick web app in headless Chromium, connected to this server like a user, and report what
// it shows.
//
//   node tests/lichtblick.mjs '{"url": "http://127.0.0.1:APP/?ds=foxglove-websocket&ds.url=ws://...", ...}'
//
// The app is a build of Lichtblick's web app (see tests/test_lichtblick.py) served on loopback, its default
// layout (the panels a first open shows) put in its index.html as its Docker image does. Options: url;
// screenshot (PNG of the page at the end); panels (ids of the layout's panels to read while it plays: a Raw
// Messages panel's text, a Plot panel's count of pixels of colour `plotColor`, looked at until it reaches `plotPixels`, default 1); until ({panel id: text} that Raw
// Messages panels show when playback is over: the panels are read until each has shown its text, or the timeout);
// timeout (ms, default 60000); viewport ({width, height}, default 1400x900); hosts (more host names the page may
// reach besides this machine's loopback).
//
// Prints one JSON object: the topics the Topics tab lists (name and schema), the problems the Problems tab lists,
// each Raw Messages panel's distinct texts in the order shown, each Plot panel's pixels of the series colour at the end,
// whether the 3D panel's canvas shows a picture (varied pixels), the page errors and console errors and warnings,
// the requests to other hosts (refused: the tests use no network).
import {drawn, launch, loopbackOnly, pixelTools} from './chromium.mjs';

const options = {timeout: 60000, viewport: {width: 1400, height: 900}, panels: [], hosts: [], plotPixels: 1, ...JSON.parse(process.argv[2])};

const browser = await launch();
const report = {topics: [], problems: [], raw: {}, plots: {}, drawn3d: false, pageErrors: [], consoleErrors: [],
  consoleWarnings: [], externalRequests: [], steps: []};
const deadline = Date.now() + options.timeout;
try {
  const page = await browser.newPage({viewport: options.viewport});
  page.on('pageerror', error => report.pageErrors.push(String(error)));
  page.on('console', message => {
    if (message.type() === 'error') report.consoleErrors.push(message.text());
    if (message.type() === 'warning') report.consoleWarnings.push(message.text());
  });
  await loopbackOnly(page, report.externalRequests, options.hosts);
  await pixelTools(page);
  await page.goto(options.url, {waitUntil: 'domcontentloaded', timeout: options.timeout});
  report.steps.push('loaded');

  // Raw Messages panels, read while the log plays; Plot panels once it is over.
  const panel = id => page.locator(`[data-testid~="${id}"]`).first();
  const rawPanels = options.panels.filter(id => id.startsWith('RawMessages!'));
  const read = async () => {
    for (const id of rawPanels) {
      const text = (await panel(id).innerText({timeout: 1000}).catch(() => '')).replace(/\s+/g, ' ').trim();
      const seen = report.raw[id] || (report.raw[id] = []);
      if (text && seen[seen.length - 1] !== text) seen.push(text);
    }
  };
  const done = () => Object.entries(options.until || {})
    .every(([id, want]) => (report.raw[id] || []).some(text => text.includes(want)));
  while (Date.now() < deadline && !done()) {
    await read();
  }
  report.steps.push(done() ? 'played' : 'timeout');
  // A Plot panel draws after the messages reach it (later on a loaded machine): looked at until it shows
  // `plotPixels` of its colour or for 10 s more.
  for (const id of options.panels.filter(id => id.startsWith('Plot!'))) {
    const until = Math.max(deadline, Date.now() + 10000);
    do {
      const shot = await panel(id).screenshot({timeout: 10000}).catch(() => null);
      if (shot) {
        report.plots[id] = await page.evaluate(([data, color]) => window.countColour(data, color), [shot.toString('base64'), options.plotColor]);
      }
    } while ((report.plots[id] || 0) < options.plotPixels && Date.now() < until);
  }

  // The 3D panel: a picture, not one flat colour (looked at until it is one: the screenshot waits for it too).
  if (await page.locator('[data-testid~="3D!xviz"]').count()) {
    report.drawn3d = await drawn(page, '3D!xviz', Math.max(deadline, Date.now() + 10000));
  }
  if (options.screenshot) await page.screenshot({path: options.screenshot});

  // The Topics tab of the left sidebar: every topic the app took, with its schema.
  const tab = async name => {
    const button = page.getByRole('tab', {name: new RegExp(`^${name}`)}).first();
    if (await button.count() === 0) return false;
    await button.click();
    return true;
  };
  if (await tab('Topics')) {
    const rows = page.locator('[data-testid="TopicListDragHandle"]');
    await rows.first().waitFor({timeout: Math.max(1000, deadline - Date.now())}).catch(() => {});
    // The list draws only the rows in view (react-window): scroll it through, gathering each row once.
    report.topics = await page.evaluate(async () => {
      const seen = new Map();
      const gather = () => document.querySelectorAll('[data-testid="TopicListDragHandle"]').forEach(handle => {
        const row = handle.parentElement.innerText.split('\n').map(line => line.trim()).filter(Boolean);
        if (row.length && !seen.has(row[0])) seen.set(row[0], row);
      });
      const first = document.querySelector('[data-testid="TopicListDragHandle"]');
      let list = first && first.parentElement;
      while (list && !(list.scrollHeight > list.clientHeight && getComputedStyle(list).overflowY !== 'visible')) {
        list = list.parentElement;
      }
      gather();
      for (let top = 0; list && top + list.clientHeight < list.scrollHeight; ) {
        top += list.clientHeight / 2;
        list.scrollTop = top;
        await new Promise(resolve => requestAnimationFrame(() => requestAnimationFrame(resolve)));
        gather();
      }
      if (list) list.scrollTop = 0;
      return [...seen.values()];
    });
    report.steps.push('topics');
  }
  if (await tab('Problems')) {
    report.problems = (await page.locator('[role="tabpanel"], .MuiAccordion-root').allInnerTexts().catch(() => []))
      .map(text => text.trim()).filter(Boolean);
    report.steps.push('problems');
  }
} catch (error) {
  report.pageErrors.push(`driver: ${error && error.stack || error}`);
} finally {
  await browser.close();
}
process.stdout.write(JSON.stringify(report));
