"""What the test suite and the benchmarks share, importable by both: ``devkit``.

Not part of the product and never in its wheel: a distribution of its own
(``devkit/pyproject.toml``), installed in editable mode by ``scripts/test.sh``
(``pip install -e ./devkit``), so that ``tests/`` and ``scripts/bench/``
import it without putting each other on ``sys.path``.

- :mod:`devkit.data`: where the real data is (``XVIZ_SHARED_DIR``, read once);
- :mod:`devkit.s3`: moto's S3 server on loopback, and uploads to it;
- :mod:`devkit.tcpproxy`: a loopback HTTP proxy that adds latency and faults, and a rate-limited TCP link;
- :mod:`devkit.tclink`: a real slow link, a veth pair into a network namespace shaped with ``tc tbf`` (root);
- :mod:`devkit.waymo_frames`: synthetic Waymo ``Frame`` records and segments;
- :mod:`devkit.rosbag_kitti`: bags written from the real KITTI raw excerpt.
"""
