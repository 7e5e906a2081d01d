// Run a scripted XVIZ session against a server with the published client
// (@xviz/parser 1.0.13), as streetscape.gl would, and print what it received.
//
//   node xviz-session.js URL (--script JSON | --script-file FILE|-) [--brief] [--validate]
//                        [--timeout-ms N]
//
// The script is a JSON array of steps, run in order once the socket is open:
//
//   {"send": VALUE}                   an object is sent as JSON text, a string verbatim;
//                                     {"$timestamp": s} anywhere in VALUE becomes the
//                                     metadata start_time + s
//   {"send_transform_log": {"id": "1", "from_start": 0.0, "to_start": 1.0, ...}}
//                                     an xviz/transform_log for [start_time + from_start,
//                                     start_time + to_start]; a missing offset leaves that
//                                     bound out, other fields go into the request as given
//   {"wait": "metadata", "count": N}  until N xviz/metadata have arrived (default 1)
//   {"wait": "state_updates", "count": N}, {"wait": "error", "count": N},
//   {"wait": "messages", "count": N}  likewise for xviz/state_update, xviz/error, any message
//   {"wait": "done", "id": "1"}       until an xviz/transform_log_done with this id (any
//                                     id if none is given) has arrived
//   {"wait": "ms", "ms": 500}         a fixed pause
//   {"close": true}                   close the socket and await the close handshake
//
// Counts are totals since the session opened. A wait fails after --timeout-ms
// (default 30000), or the step's own "timeout_ms", or as soon as the connection
// closes. start_time is what the parser made of the latest metadata, the value
// streetscape.gl computes its request windows from.
//
// Every message is decoded with parseXVIZMessageSync, which learns the XVIZ
// version from the metadata as it does in streetscape.gl. Each prints as one
// JSON line {"index", "kind", "bytes", "type", "raw", "parsed"}: "type" is the
// envelope type as @xviz/io reads it ("xviz/state_update"; null if it reads no
// XVIZ message), "raw" the envelope it unpacks, "parsed" the parser's result,
// with arrays as plain.js shows them. A message without an envelope also has
// "envelope": false; one that fails to decode has "error". With --brief only
// metadata, error and done messages keep "raw" and "parsed"; a state update
// keeps its "timestamp" and the names of the "streams" and "poses" parsed.
// With --validate every message is also checked by the published validator
// (validate.js: @xviz/schema's XVIZValidator on the envelope's data as @xviz/io
// unpacks it); a message it refuses has "invalid", the list of its errors.
// The last line is {"summary": {"messages", "by_type", "errors", "closed"}}:
// "by_type" counts messages by "type" (those of type null under "null");
// "errors" lists {"index"?, "source", "message"} for every xviz/error the
// server sent ("server"), message the client could not decode ("decode"),
// socket error ("socket"), message the validator refused ("schema", with
// --validate) and the step that failed ("script"); "closed" is
// {"code", "reason"}, or null if the socket was still open when the script
// ended. Messages arriving after the last step are not reported.
//
// Exit status: 0 when every step completed, 1 when one failed (the reason is
// on stderr and in the summary's errors), 2 for a bad command line or script.
'use strict';

const fs = require('fs');
const {parseXVIZMessageSync} = require('@xviz/parser');
const {XVIZData} = require('@xviz/io');
const WebSocket = require('ws');
const {plain} = require('./plain');
const {validateMessage} = require('./validate');

const USAGE =
  'usage: node xviz-session.js URL (--script JSON | --script-file FILE|-) ' +
  '[--brief] [--validate] [--timeout-ms N]';
const DEFAULT_TIMEOUT_MS = 30000;
// The messages that keep "raw" and "parsed" in --brief output.
const BRIEF_IN_FULL = new Set(['xviz/metadata', 'xviz/error', 'xviz/transform_log_done']);
// How long the server may take to answer our close once the report is out.
const LINGER_MS = 1000;

/** A bad command line or script: nothing was run. */
class UsageError extends Error {}

/** A step that could not complete: the session failed. */
class SessionError extends Error {}

function parseArgs(argv) {
  const options = {url: null, script: null, brief: false, validate: false, timeoutMs: DEFAULT_TIMEOUT_MS};
  for (let i = 0; i < argv.length; i++) {
    const arg = argv[i];
    const value = () => {
      if (i + 1 === argv.length) {
        throw new UsageError(`${arg} needs a value`);
      }
      return argv[++i];
    };
    if (arg === '--brief') {
      options.brief = true;
    } else if (arg === '--validate') {
      options.validate = true;
    } else if (arg === '--script') {
      options.script = parseJSON(value(), '--script');
    } else if (arg === '--script-file') {
      const file = value();
      options.script = parseJSON(readText(file), file);
    } else if (arg === '--timeout-ms') {
      options.timeoutMs = Number(value());
    } else if (!arg.startsWith('--') && options.url === null) {
      options.url = arg;
    } else {
      throw new UsageError(`unexpected argument ${arg}`);
    }
  }
  if (options.url === null || options.script === null) {
    throw new UsageError('a URL and a script are required');
  }
  if (!Array.isArray(options.script)) {
    throw new UsageError('the script must be a JSON array of steps');
  }
  checkTimeout(options.timeoutMs, '--timeout-ms');
  return options;
}

/** The text of a file, or of stdin for "-". */
function readText(file) {
  try {
    return fs.readFileSync(file === '-' ? 0 : file, 'utf8');
  } catch (error) {
    throw new UsageError(`cannot read the script: ${error.message}`);
  }
}

function parseJSON(text, source) {
  try {
    return JSON.parse(text);
  } catch (error) {
    throw new UsageError(`${source}: ${error.message}`);
  }
}

function checkTimeout(ms, source) {
  if (!(Number.isFinite(ms) && ms > 0)) {
    throw new UsageError(`${source} must be a positive number of milliseconds, not ${ms}`);
  }
}

/** Turn a script step into an action on a session, or throw UsageError. */
function compile(step, defaultTimeoutMs) {
  const text = JSON.stringify(step);
  if (!step || typeof step !== 'object') {
    throw new UsageError(`not a step: ${text}`);
  }
  const timeoutMs = step.timeout_ms === undefined ? defaultTimeoutMs : step.timeout_ms;
  checkTimeout(timeoutMs, `timeout_ms of ${text}`);
  if ('send' in step) {
    return session => session.send(step.send);
  }
  if ('send_transform_log' in step) {
    const request = transformLog(step.send_transform_log);
    return session => session.send(request);
  }
  if (step.wait === 'ms') {
    checkTimeout(step.ms, `ms of ${text}`);
    return () => new Promise(resolve => setTimeout(resolve, step.ms));
  }
  if ('wait' in step) {
    const until = condition(step);
    return session => session.until(until, timeoutMs);
  }
  if (step.close === true) {
    return session => session.close(timeoutMs);
  }
  throw new UsageError(`unknown step ${text}`);
}

function transformLog({from_start, to_start, ...data}) {
  if (from_start !== undefined) {
    data.start_timestamp = {$timestamp: from_start};
  }
  if (to_start !== undefined) {
    data.end_timestamp = {$timestamp: to_start};
  }
  return {type: 'xviz/transform_log', data};
}

/** What a wait step waits for: {what, met(session)}. */
function condition(step) {
  const count = step.count === undefined ? 1 : step.count;
  if (!(Number.isInteger(count) && count > 0)) {
    throw new UsageError(`count must be a positive integer in ${JSON.stringify(step)}`);
  }
  const counted = type => ({
    what: `${count} ${type} message(s)`,
    met: session => (session.byType[type] || 0) >= count
  });
  switch (step.wait) {
    case 'metadata':
      return counted('xviz/metadata');
    case 'state_updates':
      return counted('xviz/state_update');
    case 'error':
      return counted('xviz/error');
    case 'messages':
      return {what: `${count} message(s)`, met: session => session.received >= count};
    case 'done':
      return step.id === undefined
        ? {what: 'an xviz/transform_log_done', met: session => session.doneIds.length > 0}
        : {
            what: `xviz/transform_log_done with id ${JSON.stringify(step.id)}`,
            met: session => session.doneIds.includes(step.id)
          };
    default:
      throw new UsageError(`unknown wait ${JSON.stringify(step.wait)}`);
  }
}

/** What @xviz/io and @xviz/parser make of one message, as streetscape.gl reads it. */
function decode(payload, validate) {
  const decoded = {type: null, bare: false, raw: undefined, parsed: undefined, error: null, invalid: []};
  try {
    const message = new XVIZData(payload).message();
    if (message && message.type) {
      decoded.type = `xviz/${message.type}`;
      decoded.bare = message.message.type !== decoded.type;
      decoded.raw = message.message;
      if (validate) {
        const data = decoded.bare ? decoded.raw : decoded.raw.data;
        decoded.invalid = validateMessage({type: decoded.type, data}, typeof payload !== 'string');
      }
    }
  } catch (error) {
    decoded.error = error;
  }
  parseXVIZMessageSync(
    payload,
    result => {
      decoded.parsed = result;
    },
    error => {
      decoded.error = decoded.error || error;
    },
    {}
  );
  if (decoded.type === null && !decoded.error) {
    decoded.error = new Error('@xviz/io reads no XVIZ message in this');
  }
  return decoded;
}

function describeError(error) {
  return String(error && error.stack ? error.stack : error);
}

/** The output line for one received message. */
function messageLine(index, frame, decoded, brief) {
  const line = {index, kind: frame.kind, bytes: frame.bytes, type: decoded.type};
  if (decoded.bare) {
    line.envelope = false;
  }
  const {parsed} = decoded;
  if (!brief || BRIEF_IN_FULL.has(decoded.type)) {
    line.raw = plain(decoded.raw);
    line.parsed = plain(parsed);
  } else if (decoded.type === 'xviz/state_update' && parsed) {
    line.timestamp = parsed.timestamp;
    line.streams = Object.keys(parsed.streams || {});
    line.poses = Object.keys(parsed.poses || {});
  }
  if (decoded.error) {
    line.error = describeError(decoded.error);
  }
  if (decoded.invalid.length) {
    line.invalid = decoded.invalid;
  }
  return line;
}

function print(value) {
  process.stdout.write(JSON.stringify(value) + '\n');
}

/** One WebSocket connection, what came over it, and the waits on it. */
class Session {
  constructor(url, brief, validate) {
    this.url = url;
    this.brief = brief;
    this.validate = validate;
    this.socket = null;
    this.received = 0;
    this.byType = {};
    this.doneIds = [];
    this.errors = [];
    this.startTime = null;
    this.closed = null;
    this.finished = false;
    this.waiters = new Set();
  }

  open(timeoutMs) {
    return new Promise((resolve, reject) => {
      const socket = new WebSocket(this.url);
      // As streetscape.gl does: binary frames reach the parser as ArrayBuffers.
      socket.binaryType = 'arraybuffer';
      const timer = setTimeout(() => {
        socket.terminate();
        reject(new SessionError(`could not connect to ${this.url} within ${timeoutMs} ms`));
      }, timeoutMs);
      let opened = false;
      socket.on('open', () => {
        opened = true;
        clearTimeout(timer);
        resolve();
      });
      socket.on('error', error => {
        if (opened) {
          this.errors.push({source: 'socket', message: error.message});
        } else {
          clearTimeout(timer);
          reject(new SessionError(`could not connect to ${this.url}: ${error.message}`));
        }
      });
      socket.on('message', (data, isBinary) => this.receive(data, isBinary));
      socket.on('close', (code, reason) => {
        this.closed = {code, reason: reason.toString()};
        this.notify();
      });
      this.socket = socket;
    });
  }

  receive(data, isBinary) {
    if (this.finished) {
      return;
    }
    const frame = {kind: isBinary ? 'binary' : 'text', bytes: data.byteLength};
    // Text frames reach the parser as strings, as a browser's onmessage gives them.
    const payload = isBinary ? data : new TextDecoder().decode(data);
    const decoded = decode(payload, this.validate);
    const index = this.received++;
    this.record(index, decoded);
    print(messageLine(index, frame, decoded, this.brief));
    this.notify();
  }

  record(index, {type, raw, parsed, error, invalid}) {
    this.byType[type] = (this.byType[type] || 0) + 1;
    if (type === 'xviz/metadata' && parsed && Number.isFinite(parsed.start_time)) {
      this.startTime = parsed.start_time;
    } else if (type === 'xviz/transform_log_done') {
      this.doneIds.push(raw.data.id);
    } else if (type === 'xviz/error') {
      this.errors.push({index, source: 'server', message: raw.data.message});
    }
    if (error) {
      this.errors.push({index, source: 'decode', message: String(error.message || error)});
    }
    for (const message of invalid) {
      this.errors.push({index, source: 'schema', message: `${type}: ${message}`});
    }
  }

  notify() {
    for (const check of this.waiters) {
      check();
    }
  }

  /** Resolve once `met(this)` holds; reject on timeout or when the socket closes first. */
  until({what, met}, timeoutMs) {
    return new Promise((resolve, reject) => {
      const settle = (callback, value) => {
        clearTimeout(timer);
        this.waiters.delete(check);
        callback(value);
      };
      const check = () => {
        if (met(this)) {
          settle(resolve);
        } else if (this.closed) {
          const closed = `the connection closed (${closeText(this.closed)})`;
          const message = `${closed} while waiting for ${what}; ${this.describe()}`;
          settle(reject, new SessionError(message));
        }
      };
      const timer = setTimeout(() => {
        const message = `timed out after ${timeoutMs} ms waiting for ${what}; ${this.describe()}`;
        settle(reject, new SessionError(message));
      }, timeoutMs);
      this.waiters.add(check);
      check();
    });
  }

  send(value) {
    if (this.closed) {
      throw new SessionError(`cannot send: the connection closed (${closeText(this.closed)})`);
    }
    const text = typeof value === 'string' ? value : JSON.stringify(this.fillTimestamps(value));
    return new Promise((resolve, reject) => {
      this.socket.send(text, error =>
        error ? reject(new SessionError(`could not send: ${error.message}`)) : resolve()
      );
    });
  }

  /** Replace every {"$timestamp": s} in `value` with the metadata start_time + s. */
  fillTimestamps(value) {
    if (Array.isArray(value)) {
      return value.map(item => this.fillTimestamps(item));
    }
    if (!value || typeof value !== 'object') {
      return value;
    }
    if ('$timestamp' in value) {
      if (this.startTime === null) {
        throw new SessionError('no metadata with a start_time yet to resolve $timestamp against');
      }
      return this.startTime + value.$timestamp;
    }
    const out = {};
    for (const key of Object.keys(value)) {
      out[key] = this.fillTimestamps(value[key]);
    }
    return out;
  }

  async close(timeoutMs) {
    if (this.closed) {
      const closed = closeText(this.closed);
      throw new SessionError(`the server had already closed the connection (${closed})`);
    }
    this.socket.close(1000);
    await this.until({what: 'the close handshake', met: session => session.closed}, timeoutMs);
  }

  /** What has arrived so far, for failure messages. */
  describe() {
    let text = `received ${this.received} message(s)`;
    if (this.received) {
      text += ': ' + Object.entries(this.byType).map(([type, n]) => `${n} ${type}`).join(', ');
    }
    if (this.doneIds.length) {
      text += `; transform_log_done ids ${JSON.stringify(this.doneIds)}`;
    }
    return text;
  }

  /** Print the summary, stop reporting and close the socket if it is still open. */
  finish() {
    this.finished = true;
    const {received, byType, errors, closed} = this;
    print({summary: {messages: received, by_type: byType, errors, closed}});
    const {socket} = this;
    if (socket && socket.readyState !== WebSocket.CLOSED) {
      socket.close(1000);
      setTimeout(() => socket.terminate(), LINGER_MS).unref();
    }
  }
}

function closeText({code, reason}) {
  return reason ? `code ${code}, reason ${JSON.stringify(reason)}` : `code ${code}`;
}

async function run(session, actions, script, timeoutMs) {
  await session.open(timeoutMs);
  for (const [index, action] of actions.entries()) {
    try {
      await action(session);
    } catch (error) {
      if (!(error instanceof SessionError)) {
        throw error;
      }
      const step = JSON.stringify(script[index]);
      throw new SessionError(`step ${index + 1} ${step}: ${error.message}`);
    }
  }
}

async function main() {
  let options;
  let actions;
  try {
    options = parseArgs(process.argv.slice(2));
    actions = options.script.map(step => compile(step, options.timeoutMs));
  } catch (error) {
    if (!(error instanceof UsageError)) {
      throw error;
    }
    process.stderr.write(`xviz-session: ${error.message}\n${USAGE}\n`);
    process.exitCode = 2;
    return;
  }
  const session = new Session(options.url, options.brief, options.validate);
  try {
    await run(session, actions, options.script, options.timeoutMs);
  } catch (error) {
    if (!(error instanceof SessionError)) {
      throw error;
    }
    session.errors.push({source: 'script', message: error.message});
    process.stderr.write(`xviz-session: ${error.message}\n`);
    process.exitCode = 1;
  }
  session.finish();
}

main();
