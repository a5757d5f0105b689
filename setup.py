"""ament_python package set-up; also installs with plain pip (pip install -e '.[test,ros]').

The ``ros`` extra pulls ROS 2 Jazzy's Python client and messages from PyPI (wheels), so the
node runs, and its tests run, without a ROS installation.
"""

import os
import subprocess
import sys
from glob import glob

from setuptools import find_packages, setup
from setuptools.command.install import install

PACKAGE = "strain_comp"


class InstallPrimed(install):
    """``install``, then (an install into a prefix, as colcon's; not a wheel's staging root)
    the numba kernels of the bundled params files compiled into the installed package's
    cache (``strain_comp.ros.node.prime_cache``), so the node's first start loads them
    instead of compiling for seconds (docs/results.md). STRAIN_COMP_NO_PRIME=1 skips it;
    a failure is a note, never a failed install."""

    def run(self) -> None:
        super().run()
        if self.root is not None or os.environ.get("STRAIN_COMP_NO_PRIME"):
            return
        # run in install_lib: `python -c` puts its folder first on sys.path, so the installed
        # package is the one imported and its __pycache__ the one filled
        done = subprocess.run(
            [sys.executable, "-c", "import sys; from strain_comp.ros.node import prime_cache; "
             "print('numba cache primed for', ', '.join(prime_cache(sys.argv[1])))",
             os.path.abspath("config")], cwd=self.install_lib, check=False)
        if done.returncode != 0:
            print("strain_comp: numba cache not primed; the first start compiles")

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(include=[PACKAGE, f"{PACKAGE}.*"]),
    package_data={PACKAGE: ["py.typed"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
        (f"share/{PACKAGE}/launch", glob("launch/*.py")),
    ],
    python_requires=">=3.10",
    install_requires=[
        "numpy>=1.24",
        "scipy>=1.10",
        "numba>=0.58",
        "PyYAML>=6",
        "mcap>=1.1",
        "mcap-ros2-support>=0.6,<0.7",  # io/bag/decode.py: DecoderFactory; io/cdr.py: its encoder
        "matplotlib>=3.7",
        "threadpoolctl>=3.1",  # models/apl.py: one BLAS thread while the fit grid is scored
        "apsw>=3.43",  # io/bag/db3.py: rosbag2's sqlite3 storage (.db3); octet_length
        "tqdm>=4.60",  # progress.py: progress bars on a terminal
    ],
    extras_require={
        "test": ["pytest>=7", "pytest-xdist>=3.5",  # scripts/test.sh: -n 2
                 "hypothesis>=6", "ruff", "mypy>=1.16",
                 "types-PyYAML", "rosbags>=0.11",  # rosbags: test/io/test_db3.py writes .db3
                 "pandas>=2"],  # docs/api.md's notebook (to_frame), run by test_api_doc
        "fast": ["intel-cmplr-lib-rt"],
        "ros": ["ros-jazzy-rclpy[fastrtps]", "ros-jazzy-std-msgs", "ros-jazzy-sensor-msgs",
                "ros-jazzy-diagnostic-msgs", "ros-jazzy-std-srvs", "ros-jazzy-rosgraph-msgs",
                "colcon-common-extensions", "ros-jazzy-ament-package"],
    },
    cmdclass={"install": InstallPrimed},
    zip_safe=False,
    maintainer="strain_comp developers",
    maintainer_email="strain_comp@example.org",
    description="Calibrated strain from soft resistive strain sensors (ROS 2 Jazzy).",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "strain-comp = strain_comp.cli:main",
            # ament_python: setup.cfg installs console scripts into lib/strain_comp, where
            # `ros2 run strain_comp compensator` (and `... strain-comp`) finds them
            "compensator = strain_comp.ros.node:main",
        ],
    },
)
