from setuptools import find_packages, setup

PACKAGE = "gait_policy_node"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={PACKAGE: ["policies/*.npz"]},  # the shipped trained policy (learned_policy.SHIPPED_POLICY_FILE)
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + PACKAGE]),
        ("share/" + PACKAGE, ["package.xml"]),
        ("share/" + PACKAGE + "/config", ["../../config/gait_policy.yaml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    entry_points={
        "console_scripts": [
            "gait_policy = gait_policy_node.policy_node:main",
            "velocity_command = gait_policy_node.velocity_command:main",
            "teleop_keyboard = gait_policy_node.teleop_node:main",
            "demo_report = gait_policy_node.demo_report:main",
            "train_es = gait_policy_node.train_es:main",
            "eval_policy = gait_policy_node.eval_policy:main",
            "sweep_gaits = gait_policy_node.sweep_gaits:main",
            "compare_policies = gait_policy_node.compare_policies:main",
            "fit_policy = gait_policy_node.fit_policy:main",
            "compare_runs = gait_policy_node.compare_runs:main",
        ]
    },
)
