"""ROS bags as XVIZ: ROS 1 bags, ROS 2 bags (sqlite3 or MCAP) and bare MCAP files, converted on demand.

:class:`RosBag` is the dataset (kind ``rosbag``); :func:`is_rosbag`
recognises the three containers. The modules: :mod:`.bag` reads a bag
through its index, :mod:`.mapping` decides what each topic becomes,
:mod:`.sensors` and :mod:`.markers` convert messages, :mod:`.tf` resolves
frames, :mod:`.config` reads the TOML configuration, :mod:`.inspect`
describes a bag for ``xviz-server inspect``.
"""

from .bag import is_rosbag
from .dataset import RosBag

__all__ = ["RosBag", "is_rosbag"]
