import os

from setuptools import find_namespace_packages, setup

with open(os.path.join("sb3_pola", "version.txt")) as file_handler:
    __version__ = file_handler.read().strip()

# ONNX export (torch.onnx's exporter needs onnx and onnxscript) and ONNX Runtime to run the exported file
EXPORT_REQUIRES = ["onnx>=1.16", "onnxscript>=0.3", "onnxruntime>=1.18"]
MAZE_REQUIRES = ["gymnasium-robotics>=1.4"]
RAY_REQUIRES = ["ray>=2.10"]
ZOO_REQUIRES = ["rl_zoo3[plots]>=2.9", "requests", "tensorboard", "optuna"]

long_description = open("README.md").read() if os.path.exists("README.md") else ""

setup(
    name="sb3_pola",
    version=__version__,
    description="POLA (Policy Optimization by Looking Ahead): model-based offline RL for Stable-Baselines3",
    long_description=long_description,
    long_description_content_type="text/markdown",
    # namespace discovery: the data folders (sb3_pola/data/...) are packages too, so setuptools does not warn that
    # their files are data of a package missing from `packages`
    packages=find_namespace_packages(include=["sb3_pola", "sb3_pola.*"]),
    # hyperparams/pola.yml: the rl-zoo3 default config of `sb3-pola train|optimize`, found through importlib.resources
    package_data={"sb3_pola": ["py.typed", "version.txt", "hyperparams/*.yml", "data/**/*"]},
    include_package_data=True,
    python_requires=">=3.10",
    install_requires=[
        "stable-baselines3>=2.9,<3.0",
        # Install torch yourself first (CPU or CUDA build); the Makefile does it deliberately.
        "torch>=2.3",
        "gymnasium[mujoco]>=1.0",
        "mujoco>=3.0",
        "minari[hdf5]>=0.5.4,<0.6",
        "numpy>=1.24",
        "matplotlib",
        "tqdm",
        "rich",
        # sb3-pola score --out s3://... (with or without Ray); torch requires it already
        "fsspec",
    ],
    extras_require={
        "zoo": ZOO_REQUIRES,
        # Gymnasium-Robotics point mazes: sb3-pola collect --env PointMaze_...
        "maze": MAZE_REQUIRES,
        "export": EXPORT_REQUIRES,
        # sb3-pola score --ray (plain ray; "ray[default]" adds the dashboard)
        "ray": RAY_REQUIRES,
        # the zoo extra too: without it the zoo tests would skip silently
        "tests": ["pytest", "pytest-xdist", "pytest-timeout", *ZOO_REQUIRES, *MAZE_REQUIRES, *EXPORT_REQUIRES, *RAY_REQUIRES],
        "dev": ["ruff", "mypy", "import-linter>=2.1", "types-PyYAML", "types-requests"],
    },
    entry_points={"console_scripts": ["sb3-pola=sb3_pola.cli:main"]},
    license="MIT",
    classifiers=[
        "Programming Language :: Python :: 3",
        "Topic :: Scientific/Engineering :: Artificial Intelligence",
    ],
)
