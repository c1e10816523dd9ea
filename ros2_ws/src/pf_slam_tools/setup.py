"""pf_slam_tools: simulators and benchmarks for pf_slam (development package, plain pip)."""

from setuptools import find_packages, setup

setup(
    name="pf_slam_tools",
    version="0.1.0",
    packages=find_packages(exclude=["test", "tests"]),
    install_requires=["pf_slam_nodes"],
    zip_safe=True,
    description="Simulators and benchmarks for pf_slam (not needed at run time)",
    license="Apache-2.0",
    python_requires=">=3.10",
)
