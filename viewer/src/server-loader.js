// streetscape.gl's XVIZStreamLoader, asking the server for the state at a time it has
// not loaded (xviz/transform_point_in_time) before it asks for the frames around it.
import {LOG_STREAM_MESSAGE} from '@xviz/parser';
import {XVIZStreamLoader} from 'streetscape.gl';

/** `value` within [`low`, `high`], where those are numbers. */
function clamp(value, low, high) {
  const above = Number.isFinite(low) ? Math.max(value, low) : value;
  return Number.isFinite(high) ? Math.min(above, high) : above;
}

// What a frame of @xviz/parser's synchronizers draws, besides the vehicle's pose: each a
// stream name's data at the frame's time.
const FRAME_PARTS = ['streams', 'features', 'lookAheads', 'pointCloud', 'components', 'variables', 'links', 'poses'];

/** Whether objects `a` and `b` have the same keys, each with the same value. */
function sameEntries(a, b) {
  if (a === b) {
    return true;
  }
  if (!a || !b) {
    return false;
  }
  const keys = Object.keys(a);
  return keys.length === Object.keys(b).length && keys.every(key => a[key] === b[key]);
}

/** Whether `frame` draws what `other` draws: the same pose, and the same data for every stream. */
function sameFrame(frame, other) {
  return frame.vehiclePose === other.vehiclePose && FRAME_PARTS.every(part => sameEntries(frame[part], other[part]));
}

/**
 * The requests a loader sends on one socket: ranges of frames wait for a pending point in
 * time and, until it opens, for `gate` (a promise, or null for none).
 */
class Requests {
  constructor(socket, gate) {
    this.socket = socket;
    this.count = 0;
    this.pending = null; // the instant asked for, until a state at or before it arrives
    this.held = null; // the range asked for meanwhile
    this.gated = Boolean(gate);
    if (gate) {
      gate.then(() => this.open());
    }
  }

  transformLog({startTimestamp, endTimestamp}) {
    if (this.pending !== null || this.gated) {
      this.held = {startTimestamp, endTimestamp};
      return;
    }
    const data = {id: `${this.count++}`};
    if (Number.isFinite(startTimestamp)) {
      data.start_timestamp = startTimestamp;
    }
    if (Number.isFinite(endTimestamp)) {
      data.end_timestamp = endTimestamp;
    }
    this._send('transform_log', data);
  }

  transformPointInTime(timestamp) {
    this.pending = timestamp;
    this._send('transform_point_in_time', {id: `${this.count++}`, query_timestamp: timestamp});
  }

  /** A state for `timestamp` arrived: the range held back, if any, is asked for now (unless gated). */
  received(timestamp) {
    if (this.pending !== null && timestamp <= this.pending) {
      this.release();
    }
  }

  /** Stop waiting for the point in time (it came, or the server said it has none). */
  release() {
    this.pending = null;
    this._sendHeld();
  }

  /** Stop waiting for the gate. */
  open() {
    this.gated = false;
    this._sendHeld();
  }

  _sendHeld() {
    if (this.held) {
      const range = this.held;
      this.held = null;
      this.transformLog(range);
    }
  }

  _send(type, data) {
    this.socket.send(JSON.stringify({type: `xviz/${type}`, data}));
  }
}

/**
 * A seek to a time not loaded yet first asks for the complete state at that time (one
 * message, drawn as soon as it comes), then, once it came, for the frames around it as
 * XVIZStreamLoader does. The log's first frame is such a seek. Its buffer (the frames
 * around it) is asked for once `bufferAfter` (a promise) resolves: the page passes the
 * first frame's drawing, which the buffer's messages, parsed on the page's thread, would
 * otherwise delay. Without it, it is asked for at once. (Not an option: XVIZStreamLoader
 * puts the options it does not know in the WebSocket's URL.)
 */
export default class ServerLoader extends XVIZStreamLoader {
  constructor(options, bufferAfter = null) {
    super(options);
    const gate = bufferAfter;
    // XVIZLoaderInterface makes a new frame for every message that arrives; while the current
    // time's data stay the same (the buffer filling up around it), the frame drawn stays.
    const currentFrame = this.getCurrentFrame;
    this.getCurrentFrame = () => {
      const frame = currentFrame();
      if (!(frame && this.shownFrame && sameFrame(frame, this.shownFrame))) {
        this.shownFrame = frame;
      }
      return this.shownFrame;
    };
    // XVIZWebsocketLoader sets its socket's request sender here, as an instance property.
    this._onWSOpen = () => {
      this.xvizHandler = new Requests(this.socket, gate);
      this._onOpen();
    };
    // An xviz/error that comes while a point in time is pending is taken as its answer (the
    // parser keeps no more of an error than that it is one): the log has no state at that
    // time, say before its first frame. The range is asked for (there is no frame to draw
    // first); it is not the person's error.
    const onXVIZMessage = this.onXVIZMessage;
    this.onXVIZMessage = message => {
      if (message.type === LOG_STREAM_MESSAGE.ERROR && this.xvizHandler && this.xvizHandler.pending !== null) {
        this.xvizHandler.open();
        this.xvizHandler.release();
      } else {
        onXVIZMessage(message);
      }
    };
  }

  seek(timestamp) {
    const metadata = this.getMetadata();
    if (metadata && this.isOpen() && this.xvizHandler.pending === null) {
      const time = clamp(timestamp, this.getLogStartTime(), this.getLogEndTime());
      if (!this.bufferRange.some(([start, end]) => start <= time && time <= end)) {
        this.xvizHandler.transformPointInTime(time);
      }
    }
    super.seek(timestamp);
  }

  _onXVIZTimeslice(message) {
    super._onXVIZTimeslice(message);
    if (this.xvizHandler) {
      this.xvizHandler.received(message.timestamp);
    }
  }
}
