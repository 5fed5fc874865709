from setuptools import find_packages, setup

package_name = 'apf_swarm_nodes'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    package_data={'apf_swarm_nodes': ['py.typed']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='apf_swarm maintainers',
    maintainer_email='apf-swarm@example.com',
    description='ROS 2 nodes and the apf-swarm command line of the APF swarm.',
    license='Apache-2.0',
    # The ONE list of executables. Each is installed to lib/apf_swarm_nodes/<name>, where the
    # `ros2 run apf_swarm_nodes <name>` lookup (ament_index prefix + lib/<pkg>) finds it.
    # test/test_workspace.py checks every entry here automatically.
    entry_points={
        'console_scripts': [
            'apf-swarm = apf_swarm_nodes.cli:main',
            'tracker = apf_swarm_nodes.tracker_node:main',
            'trackers = apf_swarm_nodes.trackers_node:group_main',
            'plant = apf_swarm_nodes.plant_node:main',
            'target = apf_swarm_nodes.target_node:main',
            'recorder = apf_swarm_nodes.recorder_node:main',
            'player = apf_swarm_nodes.player_node:main',
        ],
    },
)
