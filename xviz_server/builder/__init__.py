"""Build XVIZ metadata and state updates from Python, checked as they are built.

::

    from xviz_server.builder import FrameBuilder, MetadataBuilder, ui

    meta = MetadataBuilder()
    meta.log_info(start_time=100.0, end_time=110.0)
    meta.pose("/vehicle_pose")
    meta.primitive("/objects", "POLYGON", style={"extruded": True},
                   style_classes={"Car": {"fill_color": "#50B3FF80"}})
    meta.time_series("/vehicle/velocity", "FLOAT", units="m/s")
    meta.ui_panel(ui.panel("Metrics", ui.metric(["/vehicle/velocity"], title="Velocity")))
    metadata = meta.build()

    frame = FrameBuilder(metadata)
    frame.pose("/vehicle_pose", 100.0, map_origin=(8.43, 49.01, 116.4))
    frame.polygon("/objects", [[0, 0, 0], [4, 0, 0], [4, 2, 0]], id="car-1", classes=["Car"])
    frame.time_series("/vehicle/velocity", 100.0, 12.5)
    update = frame.build()

Mistakes raise :class:`~xviz_server.exceptions.BuilderError` naming the
stream and the field; what the builders return validates against the XVIZ
schema. :class:`~xviz_server.writer.LogWriter` writes the results as a log.
"""

from ..messages import XVIZ_VERSION
from . import ui
from .frame import FrameBuilder
from .metadata import MetadataBuilder

__all__ = ["MetadataBuilder", "FrameBuilder", "ui", "XVIZ_VERSION"]
