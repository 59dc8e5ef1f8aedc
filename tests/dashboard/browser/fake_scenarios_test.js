#!/usr/bin/env node
// The page and the browser harness against the stand-in server (fake_dashboard_server.js),
// without the C++ backend: every scenario of dashboard_test.js once, and the 50 components /
// 500 skills responsiveness check. Starts each server itself and stops it by its PID.
//
//   node fake_scenarios_test.js --assets BUILD/web/dashboard [--out DIR] [--only NAME]
// Prints one line per scenario and exits 0 only if all passed. Screenshots go to DIR.
'use strict';

const { spawn } = require('node:child_process');
const fs = require('node:fs');
const path = require('node:path');
const readline = require('node:readline');

const here = __dirname;
const kScenarioTimeoutMs = 90000;

function parseArguments(argv) {
  const options = { assets: '', out: '', only: '' };
  for (let i = 2; i < argv.length; i += 2) {
    const key = argv[i];
    const value = argv[i + 1];
    if (value === undefined) throw new Error(`${key} needs a value`);
    if (key === '--assets') options.assets = value;
    else if (key === '--out') options.out = value;
    else if (key === '--only') options.only = value;
    else throw new Error(`unknown argument ${key}`);
  }
  if (!options.assets) throw new Error('usage: fake_scenarios_test.js --assets DIR [--out DIR] [--only NAME]');
  options.out = options.out || fs.mkdtempSync(path.join(require('node:os').tmpdir(), 'pnp-dashboard-shots-'));
  return options;
}

// Starts the stand-in server; resolves {child, url} once it printed its URL (bounded).
function startServer(assets, extra) {
  return new Promise((resolve, reject) => {
    const child = spawn(process.execPath, [path.join(here, 'fake_dashboard_server.js'), '--assets', assets,
                                           '--lifetime-s', '300', ...extra], { stdio: ['ignore', 'pipe', 'inherit'] });
    const timer = setTimeout(() => { child.kill('SIGKILL'); reject(new Error('fake server did not start in 10 s')); }, 10000);
    readline.createInterface({ input: child.stdout }).once('line', (line) => {
      clearTimeout(timer);
      try {
        resolve({ child, url: JSON.parse(line).url });
      } catch (error) {
        child.kill('SIGKILL');
        reject(error);
      }
    });
    child.once('exit', (code) => { clearTimeout(timer); reject(new Error(`fake server exited (${code})`)); });
  });
}

function stopServer(child) {
  return new Promise((resolve) => {
    if (child.exitCode !== null || child.signalCode !== null) return resolve();
    const timer = setTimeout(() => { child.kill('SIGKILL'); }, 3000);
    child.once('exit', () => { clearTimeout(timer); resolve(); });
    process.kill(child.pid, 'SIGTERM');
  });
}

// Runs the harness; onEvent(event, url) sees its progress lines. Resolves the result line.
function runHarness(url, args, onEvent) {
  return new Promise((resolve) => {
    const child = spawn(process.execPath, [path.join(here, 'dashboard_test.js'), '--url', url, ...args],
                        { stdio: ['ignore', 'pipe', 'inherit'] });
    const timer = setTimeout(() => child.kill('SIGKILL'), kScenarioTimeoutMs);
    let last = null;
    readline.createInterface({ input: child.stdout }).on('line', (line) => {
      let parsed;
      try { parsed = JSON.parse(line); } catch { return; }
      if (parsed.event) onEvent?.(parsed);
      else last = parsed;
    });
    child.once('exit', (code) => {
      clearTimeout(timer);
      resolve({ code, result: last || { ok: false, failures: [`harness exited ${code} without a result`] } });
    });
  });
}

async function post(url) {
  const response = await fetch(url, { method: 'POST', signal: AbortSignal.timeout(5000) });
  return response.ok;
}

const scenarios = [
  {
    name: 'run-skill',
    harness: (out) => ['--run', 'robot/Delay', '--params', '{"DurationMs":"300"}', '--expect-states', 'Running,Ready',
                       '--max-median-latency-ms', '50', '--screenshot', path.join(out, 'run-skill.png')],
    check: (r) => r.run?.statesSeen?.join(',') === 'Ready,Running,Ready' && r.latency.count >= 2,
  },
  {
    name: 'bad-parameters',
    harness: () => ['--run', 'gripper/Grasp', '--params', '{"Force":"strong"}', '--expect-run-error'],
    check: (r) => /BadTypeMismatch/.test(r.run?.error || ''),
  },
  {
    name: 'login',
    harness: () => ['--login', 'operator:operator'],
    check: (r) => r.login?.ok === true,
  },
  {
    name: 'login-refused',
    harness: () => ['--login', 'operator:wrong', '--expect-login-error'],
    check: (r) => /BadUserAccessDenied/.test(r.login?.error || ''),
  },
  {
    name: 'process',
    harness: (out) => ['--start-process', 'urn:pnp:process:demo', '--observe-ms', '3500',
                       '--screenshot', path.join(out, 'process.png')],
    check: (r) => r.process?.started === true && r.latency.count >= 8,
  },
  {
    name: 'component-gone',
    harness: () => ['--wait-gone', 'toolchanger'],
    onEvent: (event, url) => event.event === 'waiting-gone' &&
        post(`${url}fake/remove-component?name=${encodeURIComponent(event.component)}`),
    check: (r) => r.gone?.component === 'toolchanger',
  },
  {
    name: 'large-cell',
    server: ['--components', '45', '--skills-per-component', '11', '--burst-hz', '20'],
    harness: (out) => ['--run', 'device-007/Grasp', '--params', '{"Force":"10"}', '--observe-ms', '4000',
                       '--max-ready-ms', '5000', '--max-lag-ms', '500', '--screenshot', path.join(out, 'large-cell.png')],
    check: (r) => r.page?.components === 50 && r.page?.skills >= 500,
  },
];

async function main() {
  let options;
  try {
    options = parseArguments(process.argv);
  } catch (error) {
    process.stderr.write(`${error.message}\n`);
    process.exit(2);
  }
  fs.mkdirSync(options.out, { recursive: true });
  let failed = 0;
  for (const scenario of scenarios) {
    if (options.only && scenario.name !== options.only) continue;
    let server;
    try {
      server = await startServer(options.assets, scenario.server || []);
      const { result } = await runHarness(server.url, scenario.harness(options.out),
                                          (event) => scenario.onEvent?.(event, server.url));
      const ok = result.ok && scenario.check(result);
      if (!ok) ++failed;
      const summary = { scenario: scenario.name, ok, failures: result.failures, consoleErrors: result.consoleErrors,
                        latency: result.latency, responsiveness: result.responsiveness, run: result.run,
                        login: result.login, gone: result.gone, page: result.page, screenshot: result.screenshot };
      process.stdout.write(`${JSON.stringify(summary)}\n`);
    } catch (error) {
      ++failed;
      process.stdout.write(`${JSON.stringify({ scenario: scenario.name, ok: false, failures: [error.message] })}\n`);
    } finally {
      if (server) await stopServer(server.child);
    }
  }
  process.stdout.write(`${JSON.stringify({ ok: failed === 0, failed, screenshots: options.out })}\n`);
  process.exit(failed === 0 ? 0 : 1);
}

main();
