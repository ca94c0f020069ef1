"""ament_python package absscale_ros: also installable with plain pip."""
from glob import glob
import os

from setuptools import find_packages, setup

PACKAGE = 'absscale_ros'
NODES = ['frame_ingest', 'vertex_detector', 'keyframe_selector', 'sfm', 'scale',
         'bag_replay', 'video_source']


def _existing_nodes() -> list[str]:
    """Console scripts only for the nodes that exist, so installs never point at nothing."""
    here = os.path.dirname(os.path.abspath(__file__))
    return [n for n in NODES if os.path.exists(os.path.join(here, PACKAGE, 'nodes', n + '.py'))]


setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('share/' + PACKAGE + '/config', glob('config/*.yaml') + glob('config/*.xml')),
        ('share/' + PACKAGE + '/launch', glob('launch/*.launch.py')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='absscale engineers',
    maintainer_email='eng@absscale.dev',
    description='Metric 3D scanning from a single handheld camera with a calibration object.',
    license='Apache-2.0',
    python_requires='>=3.10',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [f'{n} = {PACKAGE}.nodes.{n}:main' for n in _existing_nodes()]
        + ['absscale = absscale_ros.cli:main'],
    },
)
