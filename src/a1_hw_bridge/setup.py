from setuptools import find_packages, setup

PACKAGE = "a1_hw_bridge"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + PACKAGE]),
        ("share/" + PACKAGE, ["package.xml"]),
        ("share/" + PACKAGE + "/config", ["../../config/a1_hw_bridge.yaml", "../../config/virtual_a1.yaml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    entry_points={
        "console_scripts": [
            "hw_bridge = a1_hw_bridge.node:main",
            "virtual_a1 = a1_hw_bridge.virtual_a1_node:main",
        ]
    },
)
