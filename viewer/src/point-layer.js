// Lidar points drawn as GL_POINTS: one vertex each, where deck.gl's PointCloudLayer
// draws an instanced triangle with normals and picking colours per point. The picture
// is the same (a disc of `pointSize` pixels in the point's colour, or in the colour
// the style's point_color_mode asks for); on a software renderer (SwiftShader, in
// headless browsers and machines without a GPU) a frame of 120 000 points takes
// a fraction of the time.
import {Layer, project32} from '@deck.gl/core';
import GL from '@luma.gl/constants';
import {Model} from '@luma.gl/core';

// point_color_mode, as XVIZ styles name it, and the value domain each mode colours by default.
const COLOR_MODES = {default: 0, elevation: 1, distance_to_vehicle: 2};
const COLOR_DOMAINS = {default: [0, 0], elevation: [0, 3], distance_to_vehicle: [0, 60]};
const IDENTITY = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1];

const vs = `\
#define SHADER_NAME xviz-point-layer-vertex-shader
attribute vec3 positions;
attribute vec3 positions64Low;
attribute vec4 colors;

uniform float opacity;
uniform float pointSize;
uniform int colorMode;
uniform vec2 colorDomain;
uniform mat4 vehicleDistanceTransform;

varying vec4 vColor;

// A hue from cyan (domain start) to red (domain end), at full saturation.
vec3 ramp(float value) {
  float hue = 0.5 * (1.0 - clamp((value - colorDomain.x) / (colorDomain.y - colorDomain.x), 0.0, 1.0));
  return clamp(abs(mod(hue * 6.0 + vec3(0.0, 4.0, 2.0), 6.0) - 3.0) - 1.0, 0.0, 1.0);
}

void main(void) {
  geometry.worldPosition = positions;
  gl_Position = project_position_to_clipspace(positions, positions64Low, vec3(0.0), geometry.position);
  gl_PointSize = 2.0 * pointSize * project_uDevicePixelRatio;
  if (colorMode == 1) {
    vColor = vec4(ramp((project_uModelMatrix * vec4(positions, 1.0)).z), opacity);
  } else if (colorMode == 2) {
    vColor = vec4(ramp(length((vehicleDistanceTransform * vec4(positions, 1.0)).xyz)), opacity);
  } else {
    vColor = vec4(colors.rgb, colors.a * opacity);
  }
}
`;

const fs = `\
#define SHADER_NAME xviz-point-layer-fragment-shader
precision highp float;
varying vec4 vColor;

void main(void) {
  vec2 fromCenter = 2.0 * gl_PointCoord - 1.0;
  if (dot(fromCenter, fromCenter) > 1.0) {
    discard;
  }
  gl_FragColor = vColor;
}
`;

/** A point cloud layer with the props of streetscape.gl's (pointSize in pixels, colorMode, colorDomain). */
export default class PointLayer extends Layer {
  getShaders() {
    return super.getShaders({vs, fs, modules: [project32]});
  }

  initializeState() {
    this.getAttributeManager().add({
      positions: {size: 3, type: GL.DOUBLE, fp64: this.use64bitPositions(), accessor: 'getPosition'},
      colors: {
        size: this.props.colorFormat.length,
        type: GL.UNSIGNED_BYTE,
        normalized: true,
        accessor: 'getColor',
        defaultValue: [0, 0, 0, 255]
      }
    });
  }

  updateState(params) {
    super.updateState(params);
    const {props, oldProps, changeFlags} = params;
    if (changeFlags.extensionsChanged) {
      if (this.state.model) {
        this.state.model.delete();
      }
      const model = new Model(this.context.gl, {
        ...this.getShaders(),
        id: this.props.id,
        drawMode: GL.POINTS,
        vertexCount: 1,
        isInstanced: false
      });
      this.setState({model});
      this.getAttributeManager().invalidateAll();
    }
    const moved = props.modelMatrix !== oldProps.modelMatrix || props.vehicleRelativeTransform !== oldProps.vehicleRelativeTransform;
    if (moved && props.vehicleRelativeTransform) {
      // From the layer's coordinates to the vehicle's, for colouring by distance to it.
      const toVehicle = props.vehicleRelativeTransform.clone().invert();
      if (props.modelMatrix) {
        toVehicle.multiplyRight(props.modelMatrix);
      }
      this.setState({toVehicle});
    }
  }

  draw({uniforms}) {
    const {pointSize, colorMode, colorDomain} = this.props;
    const {model, toVehicle} = this.state;
    model.setVertexCount(this.getNumInstances());
    model
      .setUniforms({
        ...uniforms,
        pointSize,
        colorMode: COLOR_MODES[String(colorMode).toLowerCase()] || 0,
        colorDomain: colorDomain || COLOR_DOMAINS[String(colorMode).toLowerCase()] || COLOR_DOMAINS.default,
        vehicleDistanceTransform: toVehicle || IDENTITY
      })
      .draw();
  }
}

PointLayer.layerName = 'XVIZPointLayer';
PointLayer.defaultProps = {
  getPosition: {type: 'accessor', value: point => point},
  getColor: {type: 'accessor', value: [0, 0, 0, 255]},
  colorFormat: 'RGBA',
  pointSize: {type: 'number', min: 0, value: 1},
  colorMode: 'default',
  colorDomain: null
};

/**
 * LogViewer's customXVIZLayers entry that draws the streams of XVIZ points with PointLayer.
 * Not pickable: a lidar point is no object, and the tooltip has nothing to say of one.
 */
export const POINT_STREAMS = {
  id: 'points',
  primitive: 'point',
  layerClass: PointLayer,
  streamMatch: (streamName, metadata) => Boolean(metadata) && String(metadata.primitive_type).toLowerCase() === 'point',
  getSubProps: () => ({pickable: false})
};
