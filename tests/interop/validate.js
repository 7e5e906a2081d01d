// Validate XVIZ messages with the published validator (@xviz/schema 1.0.13's
// XVIZValidator, the ajv draft-04 schemas the XVIZ authors publish).
//
//   node validate.js FILE...
//   node validate.js --instances FILE
//
// The first prints one JSON line per file, {"file", "type", "errors"}, or
// {"file", "error"} when @xviz/io reads no XVIZ message in it; exit status 1
// when a message is invalid or unreadable. The second reads a JSON list of
// {"schema", "instance"} (a schema name such as "style/object_value") and
// prints {"schema", "errors"} for each, or {"schema", "error"} when the
// validator has no such schema. As a module, `validateMessage(message,
// binary)` returns the errors of one envelope as @xviz/io unpacks it, and
// xviz-session.js --validate uses it on every message a session receives.
//
// What is validated is the message's data as @xviz/io's XVIZData reads it
// (JSON, GLB or PBE). A binary message holds typed arrays (points, colours,
// image bytes) where JSON has arrays and base64 text: it is first turned into
// its JSON form by @xviz/io's own JSON encoder (what its XVIZJSONWriter
// writes), since the schema describes JSON. Messages of a type without a
// schema of its own (none the server sends) are reported as such.
'use strict';

const fs = require('fs');
const {XVIZData} = require('@xviz/io');
const {XVIZValidator} = require('@xviz/schema');
const {xvizConvertJson} = require('@xviz/io/dist/es5/writers/xviz-json-encoder');

const validator = new XVIZValidator();
const PREFIX = 'Validation errors: ';

/** The errors of one envelope {type: "xviz/<name>", data}: [] when it is valid. */
function validateMessage(message, binary) {
  const name = String(message.type).replace(/^xviz\//, 'session/');
  if (!validator.hasSchema(name)) {
    return [`no schema for message type ${JSON.stringify(message.type)}`];
  }
  return validateInstance(name, binary ? xvizConvertJson(message.data) : message.data);
}

/** One ajv error as "<path>: <message> <params>". */
function describe({dataPath, message, params}) {
  return `${dataPath || '.'}: ${message} ${JSON.stringify(params)}`;
}

/** The envelope @xviz/io reads in a file or a received payload, or null. */
function unpack(payload) {
  const message = new XVIZData(payload).message();
  if (!message || !message.type) {
    return null;
  }
  const type = `xviz/${message.type}`;
  // A message without an envelope is its data.
  return {type, data: message.message.type === type ? message.message.data : message.message};
}

/** The errors of a plain JSON value against a schema of the validator, by name. */
function validateInstance(name, instance) {
  if (!validator.hasSchema(name)) {
    throw new Error(`no schema ${JSON.stringify(name)}`);
  }
  try {
    validator.validate(name, instance);
  } catch (error) {
    if (!String(error.message).startsWith(PREFIX)) {
      throw error;
    }
    return JSON.parse(error.message.slice(PREFIX.length)).map(describe);
  }
  return [];
}

function mainInstances(file) {
  for (const {schema, instance} of JSON.parse(fs.readFileSync(file, 'utf8'))) {
    const line = {schema};
    try {
      line.errors = validateInstance(schema, instance);
    } catch (error) {
      line.error = String(error.message);
    }
    process.stdout.write(JSON.stringify(line) + '\n');
  }
}

function main(files) {
  for (const file of files) {
    const buffer = fs.readFileSync(file);
    const binary = buffer[0] !== 0x7b; // a JSON message starts with "{"
    const payload = binary
      ? buffer.buffer.slice(buffer.byteOffset, buffer.byteOffset + buffer.byteLength)
      : buffer.toString('utf8');
    const line = {file};
    try {
      const message = unpack(payload);
      if (message) {
        line.type = message.type;
        line.errors = validateMessage(message, binary);
      } else {
        line.error = '@xviz/io reads no XVIZ message in this';
      }
    } catch (error) {
      line.error = String(error && error.stack ? error.stack : error);
    }
    if (line.error || line.errors.length) {
      process.exitCode = 1;
    }
    process.stdout.write(JSON.stringify(line) + '\n');
  }
}

module.exports = {validateMessage, unpack};

if (require.main === module) {
  const args = process.argv.slice(2);
  if (args[0] === '--instances') {
    mainInstances(args[1]);
  } else {
    main(args);
  }
}
