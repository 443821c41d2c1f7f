"""ament_python package setup for haptic_teleop (works with colcon and with plain pip)."""

import runpy
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup

PACKAGE = "haptic_teleop"
# One console script per live node (`ros2 run haptic_teleop master_eba`), from the node table,
# read without importing the package (it needs numpy and friends, which may not be installed yet).
NODES = runpy.run_path(str(Path(__file__).parent / PACKAGE / "nodes" / "__init__.py"))["EXECUTABLES"]

# The bundled scenes and sweeps live once, in the top-level config/ folder; wheels carry them as the
# data package haptic_teleop.config (haptic_teleop/config/ once installed), found by resources.py.
SCENES, SWEEPS, LAYOUTS = "scenes/*.yaml", "sweeps/*.yaml", "foxglove/*.json"  # inside config/
MODELS = "models/*.xml"  # inside the package folder

STANDALONE = [
    # rclpy and the standard message packages as PyPI wheels, for machines without a ROS 2 install.
    "ros-kilted-rclpy[fastrtps]>=9.1",
    "ros-kilted-std-msgs>=5.5",
    "ros-kilted-geometry-msgs>=5.5",
    "ros-kilted-sensor-msgs>=5.5",
    "ros-kilted-rosgraph-msgs>=2.3",
    "ros-kilted-diagnostic-msgs>=5.5",
    # `run --foxglove`, `launch --foxglove`: the live view's WebSocket server (record/foxglove_view.py;
    # Context, Channel(schema=dict), start_server(context=...), WebSocketServer.port as in 0.30)
    "foxglove-sdk>=0.30,<0.31",
]

# The hardware backends' SDKs (haptic_teleop/plants/dynamixel, haptic_teleop/plants/ur), imported
# only by those backends and the emulator tests: the versions the tests ran with are the floors.
HARDWARE = [
    "dynamixel-sdk>=3.8.4",
    "ur-rtde>=1.6.5",
]

# `haptic-teleop sweep --scheduler ADDRESS` (a Dask distributed cluster) and the Parquet results table
# (docs/sweep.md); without them a sweep runs in local processes and writes CSV only. Lower bounds:
# Client(address, timeout), submit(key=, pure=), Future.done/status/exception/cancel and
# LocalCluster(n_workers, processes, threads_per_worker) are in every dask release since 2023.1;
# pyarrow 16 is the first that imports under numpy 2. Tested with dask 2026.8.0, pyarrow 26.0.1.
SWEEP = [
    "dask[distributed]>=2023.1",
    "pyarrow>=16.0",
]

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=[*find_packages(exclude=["test", "test.*"]), f"{PACKAGE}.config"],
    # The models live inside the package; config/ becomes the package's config/ folder in a wheel,
    # so every install (wheel, sdist, editable, colcon) finds them (haptic_teleop/resources.py) ...
    package_dir={f"{PACKAGE}.config": "config"},
    package_data={PACKAGE: ["py.typed", MODELS], f"{PACKAGE}.config": [SCENES, SWEEPS, LAYOUTS]},
    # ... and a ROS 2 install also has them where ROS 2 tools look: share/haptic_teleop/...
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/launch", sorted(glob("launch/*_launch.py"))),
        (f"share/{PACKAGE}/config/scenes", sorted(glob(f"config/{SCENES}"))),
        (f"share/{PACKAGE}/models", sorted(glob(f"{PACKAGE}/{MODELS}"))),
        (f"share/{PACKAGE}/config/sweeps", sorted(glob(f"config/{SWEEPS}"))),
        (f"share/{PACKAGE}/config/foxglove", sorted(glob(f"config/{LAYOUTS}"))),
    ],
    python_requires=">=3.10",
    # Lower bounds: the oldest releases this package was tested with (docs/install.md, "Install"). numpy 1.25:
    # Generator.spawn; mujoco 3.3.6: mjtDisableBit.mjDSBL_ISLAND; numba 0.60: numpy 2 support.
    # mujoco, rosbags and numba have no usable rosdep key: a ROS 2 workspace installs them with pip.
    install_requires=[
        "numpy>=1.25",
        "pyyaml>=6.0",
        "mujoco>=3.3.6",
        # public API only (typestore, CDR, msgdef/hash, the sqlite3 Reader); below 0.10.10 its MCAP
        # reader skips a chunk whose first message is at time 0; tested with 0.10.10 and 0.11.9
        "rosbags>=0.10.10,<0.12",
        # MCAP chunk compression (recording.compression): lz4 frames; zstd from the standard
        # library from Python 3.14 on
        "lz4>=3.1",
        # CRC-32 at 4 to 5 times zlib's speed (ISA-L; record/crc.py falls back to zlib without it)
        "isal>=1.0",
        'backports.zstd>=1.0; python_version < "3.14"',
        # metadata.yaml reading
        "ruamel.yaml>=0.17",
        "matplotlib>=3.6",
        "tqdm>=4.64",
        # the engine's compiled loop (haptic_teleop/engine/compiled/axis_host.py); without it the Python loop runs.
        # Upper bound: the tick loops use njit's private `_nrt=False` (no reference counting; tested
        # with 0.68.1); a numba that refuses it makes the compiled loop unavailable, not wrong.
        "numba>=0.60,<0.69",
    ],
    extras_require={
        "standalone": STANDALONE,
        "hardware": HARDWARE,
        "sweep": SWEEP,
        "docs": ["mkdocs>=1.6,<2"],  # the docs site: mkdocs build --strict (docs/development.md)
        "test": [
            *HARDWARE,  # the backends are tested against emulators through the real SDKs
            *SWEEP,  # sweeps on a local Dask cluster, the Parquet table (test/test_sweep_scale.py)
            "pytest>=8.0",
            "pytest-xdist>=3.5,<4",  # the suite on two workers, real-time tests on one (test/conftest.py)
            "mkdocs>=1.6,<2",  # test/test_docs_site.py builds the docs site and checks every page, link and image
            "websockets>=13",  # test/foxglove_client.py: the Foxglove WebSocket protocol's client side (sync API)
            "hypothesis>=6.100",
            "ruff>=0.17,<0.18",
            "mypy>=1.10,<3",
            "types-PyYAML>=6.0",
            # colcon build of this package in a test (test/test_colcon.py)
            "colcon-common-extensions>=0.3",
            "ros-ament-package>=0.17",
            # a second, CRC-validating MCAP reader for the bag tests
            "mcap>=1.2",
        ],
    },
    zip_safe=False,  # MuJoCo reads the models (and their includes) from files
    maintainer="haptic_teleop maintainers",
    maintainer_email="haptic-teleop@example.org",
    description="Bilateral haptic teleoperation over imperfect networks (EBA, network shaping, playout).",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "haptic-teleop = haptic_teleop.cli.entry:main",
            # through nodes/entry.py: a signal that lands while a node is still importing is noted
            *(f"{name} = {PACKAGE}.nodes.entry:{name}" for name in NODES),
            # every node of a plan in one process: the launch files' `single_process:=true`
            "composed = haptic_teleop.live.composed:main",
        ],
    },
)
