// Connect to a server with the published Foxglove client (@foxglove/ws-protocol),
// subscribe to every channel it advertises, decode each message with the schema
// its channel advertises (protobufjs for protobuf, JSON.parse for json, the
// definition parsed by @foxglove/rosmsg and read by @foxglove/rosmsg-serialization
// for ros1 or @foxglove/rosmsg2-serialization for cdr), and print what arrived
// as one JSON object.
//
//   node foxglove-client.js URL SUBPROTOCOL [--idle-ms N] [--timeout-ms N] [--times N] [--send JSON]...
//
// It stops once no message has come for --idle-ms (default 1500) after the
// first one (with --times N: after the Nth time message, whose messages follow it), or
// after --timeout-ms (default 30000). Each --send is a text
// message sent once the channels are advertised and subscribed to.
//
// Output: {"subprotocol", "serverInfo", "channels": [{id, topic, encoding,
// schemaName, schemaEncoding}], "topics": {TOPIC: {"count", "timestamps": [ns as strings],
// "summaries": [...]}}, "arrivals": [ns as strings, every message's in the order
// they came], "times": N, "statuses": [...], "errors": [...]}.
// A summary says what the decoded message holds: for foxglove.PointCloud
// {"points", "stride", "frame_id", "fields"}; for foxglove.CompressedImage
// {"format", "magic" (first bytes, hex), "bytes"}; for foxglove.FrameTransform
// {"parent", "child", "translation"}; for foxglove.PoseInFrame {"frame_id", "position"}; for foxglove.SceneUpdate {"entities",
// "deletions"}; for JSON channels the decoded value; for sensor_msgs/PointCloud2
// {"width", "height", "point_step", "fields", "bytes", "frame_id"}; for
// sensor_msgs/Image {"encoding", "width", "height", "bytes"}; for
// sensor_msgs/CompressedImage {"format", "magic", "bytes"}; for
// tf2_msgs/TFMessage {"transforms": [{parent, child, translation, rotation}]};
// for others the keys.
'use strict';

const WebSocket = require('ws');
const {FoxgloveClient} = require('@foxglove/ws-protocol');
const protobuf = require('protobufjs');
const descriptor = require('protobufjs/ext/descriptor');
const {parse: parseDefinition} = require('@foxglove/rosmsg');
const {MessageReader: Ros1Reader} = require('@foxglove/rosmsg-serialization');
const {MessageReader: Ros2Reader} = require('@foxglove/rosmsg2-serialization');

function options(argv) {
  const out = {idleMs: 1500, timeoutMs: 30000, times: Infinity, send: []};
  const positional = [];
  for (let i = 0; i < argv.length; i++) {
    if (argv[i] === '--idle-ms') out.idleMs = Number(argv[++i]);
    else if (argv[i] === '--timeout-ms') out.timeoutMs = Number(argv[++i]);
    else if (argv[i] === '--times') out.times = Number(argv[++i]);
    else if (argv[i] === '--send') out.send.push(argv[++i]);
    else positional.push(argv[i]);
  }
  [out.url, out.subprotocol] = positional;
  return out;
}

// The client hands each message's payload over as a DataView.
function bytesOf(view) {
  return new Uint8Array(view.buffer, view.byteOffset, view.byteLength);
}

function decoderFor(channel) {
  if (channel.encoding === 'json') {
    const text = new TextDecoder();
    return data => JSON.parse(text.decode(bytesOf(data)));
  }
  if (channel.encoding === 'protobuf') {
    const bytes = Buffer.from(channel.schema, 'base64');
    const root = protobuf.Root.fromDescriptor(descriptor.FileDescriptorSet.decode(bytes));
    const type = root.lookupType(channel.schemaName);
    return data => type.toObject(type.decode(bytesOf(data)), {longs: String, bytes: Buffer});
  }
  if (channel.encoding === 'ros1' && channel.schemaEncoding === 'ros1msg') {
    const reader = new Ros1Reader(parseDefinition(channel.schema));
    return data => reader.readMessage(bytesOf(data));
  }
  if (channel.encoding === 'cdr' && channel.schemaEncoding === 'ros2msg') {
    const reader = new Ros2Reader(parseDefinition(channel.schema, {ros2: true}));
    return data => reader.readMessage(bytesOf(data));
  }
  throw new Error(`channel ${channel.topic}: no decoder for encoding ${channel.encoding} (${channel.schemaEncoding})`);
}

function stamp(header) {
  const time = header.stamp;
  return {sec: time.sec, nsec: time.nsec !== undefined ? time.nsec : time.nanosec};
}

function summary(schemaName, value) {
  switch (schemaName.replace('/msg/', '/')) {
    case 'sensor_msgs/PointCloud2':
      return {width: value.width, height: value.height, point_step: value.point_step, bytes: value.data.length,
        fields: value.fields.map(f => f.name), frame_id: value.header.frame_id, stamp: stamp(value.header)};
    case 'sensor_msgs/Image':
      return {encoding: value.encoding, width: value.width, height: value.height, bytes: value.data.length};
    case 'sensor_msgs/CompressedImage':
      return {format: value.format, magic: Buffer.from(value.data.subarray(0, 4)).toString('hex'), bytes: value.data.length};
    case 'tf2_msgs/TFMessage':
      return {transforms: value.transforms.map(t => ({parent: t.header.frame_id, child: t.child_frame_id,
        translation: t.transform.translation, rotation: t.transform.rotation}))};
    case 'foxglove.PointCloud':
      return {points: value.data.length / value.point_stride, stride: value.point_stride, frame_id: value.frame_id,
        fields: (value.fields || []).map(f => f.name)};
    case 'foxglove.CompressedImage': {
      // Bytes in protobuf; base64 text in JSON (foxglove's JSON schemas encode bytes so).
      const data = typeof value.data === 'string' ? Buffer.from(value.data, 'base64') : value.data;
      return {format: value.format, magic: Buffer.from(data.subarray(0, 4)).toString('hex'), bytes: data.length};
    }
    case 'foxglove.FrameTransform':
      return {parent: value.parent_frame_id, child: value.child_frame_id, translation: value.translation || {}};
    case 'foxglove.PoseInFrame': {
      const position = (value.pose && value.pose.position) || {};
      return {frame_id: value.frame_id, position: {x: position.x || 0, y: position.y || 0, z: position.z || 0}};
    }
    case 'foxglove.SceneUpdate':
      return {entities: (value.entities || []).length, deletions: (value.deletions || []).length};
    default:
      return Object.keys(value).sort();
  }
}

function main() {
  const opts = options(process.argv.slice(2));
  const out = {subprotocol: null, serverInfo: null, channels: [], topics: {}, arrivals: [], times: 0, statuses: [], errors: []};
  const ws = new WebSocket(opts.url, [opts.subprotocol]);
  const client = new FoxgloveClient({ws});
  const bySubscription = new Map();
  let idle = null;
  let finished = false;
  const finish = () => {
    if (finished) return;
    finished = true;
    clearTimeout(idle);
    clearTimeout(deadline);
    process.stdout.write(JSON.stringify(out) + '\n');
    client.close();
    setTimeout(() => process.exit(0), 100);
  };
  const deadline = setTimeout(() => { out.errors.push('timeout'); finish(); }, opts.timeoutMs);
  // With --times, the idle wait starts only once that many time messages have come (their messages follow them).
  const touch = () => {
    clearTimeout(idle);
    if (opts.times === Infinity || out.times >= opts.times) idle = setTimeout(finish, opts.idleMs);
  };

  ws.on('open', () => { out.subprotocol = ws.protocol; });
  client.on('error', error => out.errors.push(String(error && error.message || error)));
  client.on('serverInfo', info => { out.serverInfo = info; });
  client.on('status', status => out.statuses.push(status));
  client.on('close', () => finish());
  client.on('advertise', channels => {
    // Decoders first, then every subscription at once, as Foxglove does.
    const decodable = [];
    for (const channel of channels) {
      out.channels.push({id: channel.id, topic: channel.topic, encoding: channel.encoding, schemaName: channel.schemaName,
        schemaEncoding: channel.schemaEncoding});
      try {
        decodable.push({channel, decode: decoderFor(channel)});
      } catch (error) {
        out.errors.push(String(error.message));
      }
    }
    for (const target of decodable) {
      bySubscription.set(client.subscribe(target.channel.id), target);
      out.topics[target.channel.topic] = {count: 0, timestamps: [], summaries: []};
    }
    for (const text of opts.send) ws.send(text);
  });
  client.on('message', ({subscriptionId, timestamp, data}) => {
    touch();
    const target = bySubscription.get(subscriptionId);
    if (!target) {
      out.errors.push(`message for unknown subscription ${subscriptionId}`);
      return;
    }
    const topic = out.topics[target.channel.topic];
    topic.count += 1;
    topic.timestamps.push(String(timestamp));
    out.arrivals.push(String(timestamp));
    try {
      topic.summaries.push(summary(target.channel.schemaName, target.decode(data)));
    } catch (error) {
      out.errors.push(`${target.channel.topic}: ${error.message}`);
    }
  });
  client.on('time', () => {
    out.times += 1;
    if (out.arrivals.length > 0) touch();  // the wait starts with the first message, not the start time
  });
}

main();
