from glob import glob

from setuptools import find_packages, setup

PACKAGE = "a1_common"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + PACKAGE]),
        ("share/" + PACKAGE, ["package.xml"]),
        # Every config file, so that installed cores find the node parameter files too.
        ("share/" + PACKAGE + "/config", sorted(glob("../../config/*.yaml"))),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    entry_points={"console_scripts": []},
)
