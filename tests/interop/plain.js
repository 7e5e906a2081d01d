// Turn what the XVIZ client libraries return into plain JSON values, so that
// the Python tests can compare them exactly.
//
// Typed arrays become {"$typed", "length", "sha256"} with their "values" when
// they hold at most 1024 (or always, with `full`), else the first six as
// "head"; images and other plain byte arrays become {"$bytes", "sha256"}.
// The digest is of the array's bytes, so large point clouds compare exactly.
// Plain arrays longer than 1024 (a JSON point cloud) become {"$array",
// "sha256", "head"} unless `full`, the digest being of their JSON text.
'use strict';

const crypto = require('crypto');

const SMALL = 1024;

function digest(view) {
  const bytes = Buffer.from(view.buffer, view.byteOffset, view.byteLength);
  return crypto.createHash('sha256').update(bytes).digest('hex');
}

function plain(value, full = false) {
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
    if (!full && value.length > SMALL) {
      const text = JSON.stringify(value);
      const sha256 = crypto.createHash('sha256').update(text).digest('hex');
      return {$array: value.length, sha256, head: value.slice(0, 6).map(item => plain(item))};
    }
    return value.map(item => plain(item, full));
  }
  if (value && typeof value === 'object') {
    const out = {};
    for (const key of Object.keys(value)) {
      out[key] = plain(value[key], full);
    }
    return out;
  }
  return value;
}

module.exports = {plain};
