#!/usr/bin/env node
// Browser test of the dashboard page: headless Debian Chromium driven by puppeteer-core.
// Loads the page, fails on any console error or page error, waits for every component of
// the server's snapshot (GET /api/snapshot) to be shown, and runs the scenario given on the
// command line. Prints one JSON result line on stdout (and progress lines {"event": ...}
// before it); exit code 0 when every check passed, 1 when one failed, 2 on bad usage.
//
//   node dashboard_test.js --url http://127.0.0.1:8080/ [--screenshot out.png]
//     [--login USER:PASSWORD]              log in first; the reply must be ok
//     [--expect-login-error]               instead: the server's refusal must be shown
//     [--run SKILL]                        SKILL: its id, or COMPONENT/NAME; click Run, Start
//     [--params '{"Name":"text"}']         parameter texts typed into the Run form
//     [--expect-states Running,Ready]      states the skill's cell must show, in this order
//     [--expect-run-error]                 instead: the server's error must be shown and the
//                                          skill must not leave its state
//     [--start-process IRI]                click Start process; the process panel must show it
//     [--min-components N]                 first wait (60 s at most) until the dashboard knows N
//     [--wait-gone COMPONENT]              prints {"event":"waiting-gone",...}; the caller kills
//                                          the component; its card must disappear
//     [--observe-ms 0]                     keep watching (latencies, responsiveness) this long
//     [--max-median-latency-ms X] [--max-lag-ms Y] [--max-ready-ms Z]
//     [--timeout-ms 60000]                 bound of the whole test (each wait is bounded too)
//     [--chromium /usr/bin/chromium] [--window 1400x1000]
'use strict';

const fs = require('node:fs');
const os = require('node:os');
const path = require('node:path');

const kUsage = 'usage: dashboard_test.js --url URL [--screenshot PATH] [--login USER:PASSWORD [--expect-login-error]] ' +
    '[--run SKILL [--params JSON] [--expect-states A,B | --expect-run-error]] [--start-process IRI] ' +
    '[--min-components N] [--wait-gone COMPONENT] [--observe-ms MS] [--max-median-latency-ms X] [--max-lag-ms Y] ' +
    '[--max-ready-ms Z] [--timeout-ms MS] [--chromium PATH] [--window WxH]';

// Chromium's flags on this machine: no GPU, and no background connections (the network is
// closed; without these flags Chromium keeps trying to reach Google's hosts).
const kChromiumFlags = ['--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
                        '--disable-background-networking', '--disable-component-update',
                        '--disable-sync',
                        // WebGL without a GPU: SwiftShader, software rendering, for the 3D view
                        '--enable-unsafe-swiftshader'];

function parseArguments(argv) {
  const options = {
    url: '', screenshot: '', login: '', expectLoginError: false, run: '', params: {}, expectStates: ['Running', 'Ready'],
    expectRunError: false, startProcess: '', waitGone: '', observeMs: 0, maxMedianLatencyMs: null,
    maxLagMs: null, maxReadyMs: null, timeoutMs: 60000, chromium: '/usr/bin/chromium',
    window: [1400, 1000],
  };
  const value = (i) => {
    if (i + 1 >= argv.length) throw new Error(`${argv[i]} needs a value`);
    return argv[i + 1];
  };
  const number = (i, min, max) => {
    const n = Number(value(i));
    if (!Number.isFinite(n) || n < min || n > max) throw new Error(`${argv[i]}: ${value(i)} not in [${min}, ${max}]`);
    return n;
  };
  for (let i = 2; i < argv.length; ++i) {
    switch (argv[i]) {
      case '--url': options.url = value(i++); break;
      case '--screenshot': options.screenshot = value(i++); break;
      case '--login': options.login = value(i++); break;
      case '--expect-login-error': options.expectLoginError = true; break;
      case '--run': options.run = value(i++); break;
      case '--params': {
        const parsed = JSON.parse(value(i++));
        if (!parsed || typeof parsed !== 'object' || Array.isArray(parsed)) throw new Error('--params: a JSON object');
        options.params = Object.fromEntries(Object.entries(parsed).map(([k, v]) => [k, String(v)]));
        break;
      }
      case '--expect-states': options.expectStates = value(i++).split(',').filter(Boolean); break;
      case '--expect-run-error': options.expectRunError = true; break;
      case '--start-process': options.startProcess = value(i++); break;
      case '--wait-gone': options.waitGone = value(i++); break;
      case '--min-components': options.minComponents = number(i++, 0, 100000); break;
      case '--observe-ms': options.observeMs = number(i++, 0, 600000); break;
      case '--max-median-latency-ms': options.maxMedianLatencyMs = number(i++, 0, 1e6); break;
      case '--max-lag-ms': options.maxLagMs = number(i++, 0, 1e6); break;
      case '--max-ready-ms': options.maxReadyMs = number(i++, 0, 1e6); break;
      case '--timeout-ms': options.timeoutMs = number(i++, 1000, 3600000); break;
      case '--chromium': options.chromium = value(i++); break;
      case '--window': {
        const match = /^(\d{3,4})x(\d{3,4})$/.exec(value(i++));
        if (!match) throw new Error('--window: WxH');
        options.window = [Number(match[1]), Number(match[2])];
        break;
      }
      case '--help': throw new Error(kUsage);
      default: throw new Error(`unknown argument ${argv[i]}\n${kUsage}`);
    }
  }
  if (!options.url) throw new Error(`--url is required\n${kUsage}`);
  if (!options.url.endsWith('/')) options.url += '/';
  return options;
}

const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));

// Rejects after ms with a message naming what was awaited.
function bounded(promise, ms, what) {
  let timer;
  return Promise.race([
    promise,
    new Promise((_, reject) => { timer = setTimeout(() => reject(new Error(`timeout after ${ms} ms: ${what}`)), ms); }),
  ]).finally(() => clearTimeout(timer));
}

function progress(event) { process.stdout.write(`${JSON.stringify(event)}\n`); }

function statistics(values) {
  if (!values.length) return { count: 0, medianMs: null, p95Ms: null, maxMs: null };
  const sorted = [...values].sort((a, b) => a - b);
  const at = (q) => sorted[Math.min(sorted.length - 1, Math.floor(q * (sorted.length - 1) + 0.5))];
  const mid = sorted.length >> 1;
  const median = sorted.length % 2 ? sorted[mid] : (sorted[mid - 1] + sorted[mid]) / 2;
  return { count: sorted.length, medianMs: median, p95Ms: at(0.95), maxMs: sorted[sorted.length - 1] };
}

// The components the page must show: those of the snapshot, keyed as the page keys them
// (uri, else name), plus the components of skills that are not listed themselves.
async function expectedComponents(url, timeoutMs) {
  const response = await fetch(new URL('api/snapshot', url), { signal: AbortSignal.timeout(timeoutMs) });
  if (!response.ok) throw new Error(`GET /api/snapshot: HTTP ${response.status}`);
  const snapshot = await response.json();
  const keys = new Map();  // key -> display name
  for (const c of Array.isArray(snapshot.components) ? snapshot.components : []) {
    const key = c && (c.id ?? c.uri ?? c.applicationUri ?? c.name);
    if (key !== undefined && key !== null) keys.set(String(key), c.name || String(key));
  }
  for (const s of Array.isArray(snapshot.skills) ? snapshot.skills : []) {
    const key = s && (s.componentId ?? s.componentUri ?? s.component);
    if (key !== undefined && key !== null && !keys.has(String(key))) keys.set(String(key), s.component || String(key));
  }
  return keys;
}

async function main() {
  let options;
  try {
    options = parseArguments(process.argv);
  } catch (error) {
    process.stderr.write(`${error.message}\n`);
    process.exit(2);
  }
  const started = Date.now();
  const result = { ok: false, url: options.url, failures: [], consoleErrors: [], warnings: [] };
  const fail = (text) => result.failures.push(text);
  const remaining = () => Math.max(1000, options.timeoutMs - (Date.now() - started));
  const step = (ms) => Math.min(ms, remaining());

  let puppeteer;
  try {
    puppeteer = require('puppeteer-core');
  } catch (error) {
    process.stdout.write(`${JSON.stringify({ ok: false, failures: [`puppeteer-core not installed (npm ci): ${error.message}`] })}\n`);
    process.exit(1);
  }

  const profile = fs.mkdtempSync(path.join(os.tmpdir(), 'pnp-dashboard-chromium-'));
  let browser = null;
  let finished = false;
  const killBrowser = () => {
    const child = browser?.process();
    if (child && child.exitCode === null && child.signalCode === null) {
      try { process.kill(child.pid, 'SIGKILL'); } catch { /* already gone */ }
    }
  };
  const cleanUp = () => {
    killBrowser();
    try { fs.rmSync(profile, { recursive: true, force: true }); } catch { /* best effort */ }
  };
  const emergencyExit = (reason) => {
    if (finished) return;
    finished = true;
    fail(reason);
    cleanUp();
    process.stdout.write(`${JSON.stringify({ ...result, ok: false, durationMs: Date.now() - started })}\n`);
    process.exit(1);
  };
  // The whole test is bounded even if a CDP call hangs.
  const watchdog = setTimeout(() => emergencyExit(`watchdog: the test exceeded ${options.timeoutMs + 15000} ms`),
                              options.timeoutMs + 15000);
  process.on('SIGTERM', () => emergencyExit('terminated (SIGTERM)'));
  process.on('SIGINT', () => emergencyExit('interrupted (SIGINT)'));

  try {
    // A cell that was just started: its components are still being detected; wait (bounded)
    // until the dashboard knows at least --min-components of them.
    let expected = await bounded(expectedComponents(options.url, step(10000)), step(12000), 'GET /api/snapshot');
    for (const until = Date.now() + step(60000); expected.size < (options.minComponents || 0) && Date.now() < until;) {
      await new Promise((resolve) => setTimeout(resolve, 200));
      expected = await bounded(expectedComponents(options.url, step(10000)), step(12000), 'GET /api/snapshot');
    }
    result.components = { expected: expected.size, shown: 0, missing: [] };

    browser = await bounded(puppeteer.launch({
      executablePath: options.chromium,
      headless: true,
      pipe: true,
      userDataDir: profile,
      args: [...kChromiumFlags, `--window-size=${options.window[0]},${options.window[1]}`],
      defaultViewport: { width: options.window[0], height: options.window[1] },
      protocolTimeout: 30000,
      handleSIGINT: false, handleSIGTERM: false, handleSIGHUP: false,
      timeout: 30000,
    }), step(35000), 'Chromium start');
    result.browser = await browser.version();

    const page = await browser.newPage();
    page.setDefaultTimeout(step(30000));
    page.on('console', (message) => {
      const text = `${message.text()}${message.location()?.url ? ` (${message.location().url})` : ''}`;
      if (message.type() === 'error') result.consoleErrors.push(text);
      else if (message.type() === 'warn' && result.warnings.length < 20) result.warnings.push(text);
    });
    page.on('pageerror', (error) => result.consoleErrors.push(`page error: ${error.message}`));
    page.on('requestfailed', (request) => {
      // A WebSocket closed by the test's own kill is not a page fault; everything else is.
      result.consoleErrors.push(`request failed: ${request.url()}: ${request.failure()?.errorText}`);
    });

    await bounded(page.goto(options.url, { waitUntil: 'load', timeout: step(30000) }), step(32000), 'page load');
    await page.waitForFunction(() => window.pnpDashboard && window.pnpDashboard.ready === true,
                               { timeout: step(20000) });
    // Settled: the 3D view's one-time start (three.js parsed, shaders compiled: long with
    // software WebGL) is over, so what follows measures the page in its steady state.
    try {
      await page.waitForFunction(() => window.pnpDashboard.settled === true, { timeout: step(30000) });
    } catch {
      fail('the page did not settle (3D view start) within 30 s');
    }
    const readiness = await page.evaluate(() => ({
      readyMs: window.pnpDashboard.readyAtMs, snapshotApplyMs: window.pnpDashboard.snapshotApplyMs,
      view3d: window.pnpDashboard.view3d, view3dStartMs: window.pnpDashboard.view3dStartMs,
    }));
    result.responsiveness = { ...readiness };
    // Latencies count from here: transitions that waited for the one-time start are reported
    // apart (latencyDuringStart), the target is about the page at work.
    const latencyStart = await page.evaluate(() => window.pnpDashboard.transitionLatencies.length);

    // Every component of the snapshot is shown.
    const keys = [...expected.keys()];
    try {
      await page.waitForFunction((wanted) => wanted.every((key) =>
          document.querySelector(`[data-component-key="${CSS.escape(key)}"]`)), { timeout: step(20000) }, keys);
    } catch { /* reported below */ }
    const missing = await page.evaluate((wanted) => wanted.filter((key) =>
        !document.querySelector(`[data-component-key="${CSS.escape(key)}"]`)), keys);
    result.components.shown = keys.length - missing.length;
    result.components.missing = missing;
    if (missing.length) fail(`components not shown: ${missing.slice(0, 10).join(', ')}`);
    progress({ event: 'components-shown', count: result.components.shown });

    if (options.login) {
      const colon = options.login.indexOf(':');
      const [user, password] = colon < 0 ? [options.login, ''] : [options.login.slice(0, colon), options.login.slice(colon + 1)];
      await page.type('#login-user', user);
      await page.type('#login-password', password);
      const errorsBefore = await page.$$eval('[data-error]', (nodes) => nodes.length);
      await page.click('#login button[type=submit]');
      if (options.expectLoginError) {
        try {
          await page.waitForFunction((n) => document.querySelectorAll('[data-error]').length > n,
                                     { timeout: step(15000) }, errorsBefore);
          const error = await page.$eval('[data-error] .error-text', (n) => n.textContent);
          const status = await page.$eval('#login-status', (n) => n.textContent);
          result.login = { user, ok: false, error, status };
          if (status.includes(`logged in as ${user}`)) fail(`refused login of ${user} shown as logged in`);
        } catch {
          fail(`no error shown for the login of ${user}`);
        }
      } else {
        try {
          await page.waitForFunction((u) => document.getElementById('login-status').textContent === `logged in as ${u}`,
                                     { timeout: step(15000) }, user);
          result.login = { user, ok: true };
        } catch {
          const errors = await page.$$eval('[data-error] .error-text', (nodes) => nodes.map((n) => n.textContent));
          result.login = { user, ok: false, errors };
          fail(`login as ${user} not confirmed: ${errors.join('; ') || 'no reply'}`);
        }
      }
    }

    if (options.run) await runSkill(page, options, result, fail, step);

    if (options.startProcess) {
      await page.type('#process-iri', options.startProcess);
      await page.click('#process-start button[type=submit]');
      try {
        await page.waitForFunction((iri) => document.getElementById('process-view').textContent.includes(iri),
                                   { timeout: step(15000) }, options.startProcess);
        result.process = { started: true };
      } catch {
        fail(`process ${options.startProcess} not shown`);
      }
    }

    if (options.waitGone) {
      const key = await page.evaluate((name) => {
        const card = [...document.querySelectorAll('[data-component-key]')].find((c) =>
            [c.dataset.componentKey, c.dataset.componentName, c.dataset.componentUri,
             c.dataset.componentAppName].includes(name));
        return card ? card.dataset.componentKey : null;
      }, options.waitGone);
      if (!key) {
        fail(`component ${options.waitGone} not shown before it was to disappear`);
      } else {
        const since = Date.now();
        progress({ event: 'waiting-gone', component: options.waitGone });
        try {
          await page.waitForFunction((k) => !document.querySelector(`[data-component-key="${CSS.escape(k)}"]`),
                                     { timeout: step(30000), polling: 50 }, key);
          result.gone = { component: options.waitGone, afterMs: Date.now() - since };
        } catch {
          fail(`component ${options.waitGone} still shown after ${Date.now() - since} ms`);
        }
      }
    }

    // Responsiveness: the longest gap of a 10 ms timer while the page works (messages flowing).
    const observeMs = Math.min(options.observeMs, Math.max(0, remaining() - 8000));
    const lag = await page.evaluate((ms) => new Promise((resolve) => {
      let last = performance.now();
      let worst = 0;
      const started = last;
      const timer = setInterval(() => {
        const now = performance.now();
        worst = Math.max(worst, now - last - 10);
        last = now;
        if (now - started >= ms) {
          clearInterval(timer);
          resolve(worst);
        }
      }, 10);
    }), Math.max(observeMs, 200));
    result.responsiveness.maxLagMs = Math.round(lag * 10) / 10;

    const page_state = await page.evaluate(() => ({
      latencies: window.pnpDashboard.transitionLatencies.slice(),
      messages: window.pnpDashboard.messages,
      components: document.querySelectorAll('[data-component-key]').length,
      skills: document.querySelectorAll('[data-skill-id].skill').length,
      view3d: window.pnpDashboard.view3d,
      view3dNote: document.getElementById('view3d-status').textContent,
    }));
    result.latency = statistics(page_state.latencies.slice(latencyStart));
    result.latencyDuringStart = statistics(page_state.latencies.slice(0, latencyStart));
    result.page = { messages: page_state.messages, components: page_state.components, skills: page_state.skills,
                    view3d: page_state.view3d, view3dNote: page_state.view3dNote };

    if (options.screenshot) {
      fs.mkdirSync(path.dirname(path.resolve(options.screenshot)), { recursive: true });
      // The viewport (--window): the overview a reader sees first; a full page of 500 skills is
      // metres long and its off-screen cards are not rendered (content-visibility).
      await page.evaluate(() => window.scrollTo(0, 0));  // a click may have scrolled the page
      await page.evaluate(() => new Promise((resolve) => requestAnimationFrame(() => requestAnimationFrame(resolve))));
      await bounded(page.screenshot({ path: options.screenshot }), step(20000), 'screenshot');
      result.screenshot = path.resolve(options.screenshot);
    }

    if (options.maxMedianLatencyMs !== null && result.latency.count > 0 &&
        result.latency.medianMs > options.maxMedianLatencyMs) {
      fail(`median transition latency ${result.latency.medianMs} ms > ${options.maxMedianLatencyMs} ms`);
    }
    if (options.maxLagMs !== null && result.responsiveness.maxLagMs > options.maxLagMs) {
      fail(`page blocked for ${result.responsiveness.maxLagMs} ms > ${options.maxLagMs} ms`);
    }
    if (options.maxReadyMs !== null && !(result.responsiveness.readyMs <= options.maxReadyMs)) {
      fail(`page ready after ${result.responsiveness.readyMs} ms > ${options.maxReadyMs} ms`);
    }
  } catch (error) {
    fail(error.message.split('\n')[0]);
  }

  if (result.consoleErrors.length) fail(`${result.consoleErrors.length} console error(s)`);
  result.ok = result.failures.length === 0;
  result.durationMs = Date.now() - started;
  if (browser) {
    try { await bounded(browser.close(), 5000, 'browser close'); } catch { /* killed below */ }
  }
  finished = true;
  clearTimeout(watchdog);
  cleanUp();
  process.stdout.write(`${JSON.stringify(result)}\n`);
  process.exit(result.ok ? 0 : 1);
}

// A real mouse click, after the element was scrolled into view and the page drew twice: cards
// off-screen are not rendered (content-visibility), so their layout settles only once shown.
async function clickWhenSettled(page, selector) {
  await page.$eval(selector, (node) => node.scrollIntoView({ block: 'center' }));
  await page.evaluate(() => new Promise((resolve) => requestAnimationFrame(() => requestAnimationFrame(resolve))));
  await page.click(selector);
}

// Finds the skill (id or COMPONENT/NAME), watches its state cell, clicks Run, fills the form,
// clicks Start, then waits for the expected states (or the server's error).
async function runSkill(page, options, result, fail, step) {
  const id = await page.evaluate((wanted) => {
    const rows = [...document.querySelectorAll('tr.skill[data-skill-id]')];
    const byId = rows.find((r) => r.dataset.skillId === wanted);
    if (byId) return byId.dataset.skillId;
    const slash = wanted.lastIndexOf('/');
    const component = wanted.slice(0, slash);
    const name = wanted.slice(slash + 1);
    const row = rows.find((r) => {
      const card = r.closest('[data-component-key]');
      return r.dataset.skillName === name && card &&
             [card.dataset.componentKey, card.dataset.componentName, card.dataset.componentUri,
              card.dataset.componentAppName].includes(component);
    });
    return row ? row.dataset.skillId : null;
  }, options.run);
  result.run = { skill: options.run, id, statesSeen: [] };
  if (!id) {
    fail(`skill ${options.run} not shown`);
    return;
  }
  // Every state the cell shows, in order, from now on.
  await page.evaluate((skillId) => {
    const row = document.querySelector(`tr.skill[data-skill-id="${CSS.escape(skillId)}"]`);
    const cell = row.querySelector('.state');
    window.__pnpSeenStates = [cell.textContent];
    window.__pnpErrorsBefore = document.querySelectorAll('[data-error]').length;
    new MutationObserver(() => {
      const seen = window.__pnpSeenStates;
      if (seen[seen.length - 1] !== cell.textContent && seen.length < 1000) seen.push(cell.textContent);
    }).observe(cell, { childList: true, characterData: true, subtree: true });
  }, id);
  const rowSelector = `tr.skill[data-skill-id="${id.replace(/["\\]/g, '\\$&')}"]`;
  const formSelector = `tr[data-run-form="${id.replace(/["\\]/g, '\\$&')}"]`;
  await clickWhenSettled(page, `${rowSelector} button[data-action="run"]`);
  await page.waitForSelector(formSelector, { timeout: step(10000) });
  for (const [name, text] of Object.entries(options.params)) {
    const input = await page.$(`${formSelector} input[data-parameter="${name.replace(/["\\]/g, '\\$&')}"]`);
    if (!input) {
      fail(`the Run form of ${options.run} has no parameter ${name}`);
      return;
    }
    await input.type(text);
  }
  await clickWhenSettled(page, `${formSelector} button[data-action="run-send"]`);

  if (options.expectRunError) {
    try {
      await page.waitForFunction(() => document.querySelectorAll('[data-error]').length > window.__pnpErrorsBefore,
                                 { timeout: step(15000) });
      result.run.error = await page.$eval('[data-error] .error-text', (n) => n.textContent);
    } catch {
      fail(`no error shown for the run of ${options.run}`);
    }
    await sleep(Math.min(1000, step(1000)));  // "nothing else happens": no state change after the error
    result.run.statesSeen = await page.evaluate(() => window.__pnpSeenStates);
    if (result.run.statesSeen.length > 1) fail(`${options.run} changed state after a refused run: ${result.run.statesSeen.join(' → ')}`);
    return;
  }
  const wanted = options.expectStates;
  try {
    await page.waitForFunction((expectedStates) => {
      let at = 0;
      for (const state of window.__pnpSeenStates.slice(1)) if (state === expectedStates[at]) ++at;
      return at >= expectedStates.length;
    }, { timeout: step(30000), polling: 50 }, wanted);
  } catch {
    const errors = await page.$$eval('[data-error] .error-text', (nodes) => nodes.map((n) => n.textContent));
    fail(`${options.run}: states ${wanted.join(' → ')} not all shown` + (errors.length ? ` (errors: ${errors.join('; ')})` : ''));
  }
  result.run.statesSeen = await page.evaluate(() => window.__pnpSeenStates);
  progress({ event: 'run-done', skill: options.run, states: result.run.statesSeen });
}

main();
