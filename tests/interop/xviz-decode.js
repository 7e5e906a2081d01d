// Decode XVIZ messages with the published client (@xviz/parser 1.0.13) and
// print what it made of them, one JSON line per message, for the Python tests.
//
//   node xviz-decode.js [--full] FILE...
//
// Each line is {"file", "raw", "parsed"} or {"file", "error"}: "raw" is the
// envelope as @xviz/io unpacks it, "parsed" what parseXVIZMessageSync returns
// (what streetscape.gl draws from). Files are parsed in order, so a metadata
// message sets the XVIZ version for the updates after it, as in a session.
// Typed arrays print as {"$typed", "length", "sha256"} with their "values"
// when they hold at most 1024 (or with --full), else the first six as "head";
// images and other plain byte arrays print as {"$bytes", "sha256"}.
'use strict';

const crypto = require('crypto');
const fs = require('fs');
const {parseXVIZMessageSync} = require('@xviz/parser');
const {XVIZData} = require('@xviz/io');

const args = process.argv.slice(2);
const full = args[0] === '--full';
const files = full ? args.slice(1) : args;
const SMALL = 1024;

function digest(view) {
  const bytes = Buffer.from(view.buffer, view.byteOffset, view.byteLength);
  return crypto.createHash('sha256').update(bytes).digest('hex');
}

function plain(value) {
  if (ArrayBuffer.isView(value)) {
    // @xviz/io marks arrays that came from glTF accessors with .accessor.
    if (value instanceof Uint8Array && !value.accessor && value.constructor === Uint8Array) {
      return {$bytes: value.length, sha256: digest(value)};
    }
    const out = {$typed: value.constructor.name, length: value.length, sha256: digest(value)};
    if (full || value.length <= SMALL) {
      out.values = Array.from(value);
    } else {
      out.head = Array.from(value.subarray(0, 6));
    }
    return out;
  }
  if (Array.isArray(value)) {
    return value.map(plain);
  }
  if (value && typeof value === 'object') {
    const out = {};
    for (const key of Object.keys(value)) {
      out[key] = plain(value[key]);
    }
    return out;
  }
  return value;
}

for (const file of files) {
  const buffer = fs.readFileSync(file);
  const data = buffer.buffer.slice(buffer.byteOffset, buffer.byteOffset + buffer.byteLength);
  const line = {file};
  try {
    const message = new XVIZData(data).message();
    line.raw = plain(message.message);
    parseXVIZMessageSync(
      data,
      result => {
        line.parsed = plain(result);
      },
      error => {
        line.error = String(error && error.stack ? error.stack : error);
      },
      {}
    );
  } catch (error) {
    line.error = String(error && error.stack ? error.stack : error);
  }
  process.stdout.write(JSON.stringify(line) + '\n');
}
