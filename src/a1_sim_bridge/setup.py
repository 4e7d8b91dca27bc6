from setuptools import find_packages, setup

PACKAGE = "a1_sim_bridge"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + PACKAGE]),
        ("share/" + PACKAGE, ["package.xml"]),
        ("share/" + PACKAGE + "/config", ["../../config/a1_sim_bridge.yaml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    entry_points={
        "console_scripts": [
            "sim_bridge = a1_sim_bridge.node:main",
            "joint_hold = a1_sim_bridge.joint_hold_node:main",
            "robot_state_monitor = a1_sim_bridge.monitor_node:main",
            "flight_recorder_plot = a1_sim_bridge.flight_recorder:main",
        ]
    },
)
