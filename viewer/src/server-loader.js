// streetscape.gl's XVIZStreamLoader, asking the server for the state at a time it has
// not loaded (xviz/transform_point_in_time) before it asks for the frames around it.
import {LOG_STREAM_MESSAGE} from '@xviz/parser';
import {XVIZStreamLoader} from 'streetscape.gl';

/** `value` within [`low`, `high`], where those are numbers. */
function clamp(value, low, high) {
  const above = Number.isFinite(low) ? Math.max(value, low) : value;
  return Number.isFinite(high) ? Math.min(above, high) : above;
}

/** The requests a loader sends on one socket: ranges of frames wait for a pending point in time. */
class Requests {
  constructor(socket) {
    this.socket = socket;
    this.count = 0;
    this.pending = null; // the instant asked for, until a state at or before it arrives
    this.held = null; // the range asked for meanwhile
  }

  transformLog({startTimestamp, endTimestamp}) {
    if (this.pending !== null) {
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

  /** A state for `timestamp` arrived: the range held back, if any, is asked for now. */
  received(timestamp) {
    if (this.pending !== null && timestamp <= this.pending) {
      this.release();
    }
  }

  /** Stop waiting for the point in time (it came, or the server said it has none). */
  release() {
    this.pending = null;
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
 * XVIZStreamLoader does. The log's first frame is such a seek: it is drawn before the
 * rest of the buffer is on its way.
 */
export default class ServerLoader extends XVIZStreamLoader {
  constructor(options) {
    super(options);
    // XVIZWebsocketLoader sets its socket's request sender here, as an instance property.
    this._onWSOpen = () => {
      this.xvizHandler = new Requests(this.socket);
      this._onOpen();
    };
    // An xviz/error that comes while a point in time is pending is taken as its answer (the
    // parser keeps no more of an error than that it is one): the log has no state at that
    // time, say before its first frame. The range is asked for; it is not the person's error.
    const onXVIZMessage = this.onXVIZMessage;
    this.onXVIZMessage = message => {
      if (message.type === LOG_STREAM_MESSAGE.ERROR && this.xvizHandler && this.xvizHandler.pending !== null) {
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
