from setuptools import find_packages, setup

PACKAGE = "convex_mpc_node"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + PACKAGE]),
        ("share/" + PACKAGE, ["package.xml"]),
        ("share/" + PACKAGE + "/config", ["../../config/convex_mpc.yaml", "../../config/convex_mpc_realtime.yaml",
                                               "../../config/gaits.yaml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    entry_points={"console_scripts": ["convex_mpc = convex_mpc_node.node:main"]},
)
