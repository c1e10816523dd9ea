"""pf_slam_nodes: ament_python package (colcon) that also installs with plain pip."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "pf_slam_nodes"
NODES = ["bag_replay", "predictor", "correlator", "mapper", "texture"]

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "tests"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml") + glob("config/*.xml")),
        (f"share/{PACKAGE}/launch", glob("launch/*.py")),
        (f"share/{PACKAGE}/urdf", glob("urdf/*.urdf")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="pf_slam maintainers",
    maintainer_email="maintainers@pf-slam.org",
    description="Online particle-filter SLAM as a ROS 2 node graph",
    license="Apache-2.0",
    python_requires=">=3.10",
    entry_points={
        "console_scripts": ["pf-slam = pf_slam_nodes.cli:main"] + [f"{n} = {PACKAGE}.nodes.{n}:main" for n in NODES],
    },
)
