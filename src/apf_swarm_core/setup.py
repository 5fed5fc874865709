from setuptools import find_packages, setup

package_name = 'apf_swarm_core'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    package_data={'apf_swarm_core': ['py.typed']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools', 'numpy', 'scipy', 'pyyaml'],
    zip_safe=True,
    maintainer='apf_swarm maintainers',
    maintainer_email='apf-swarm@example.com',
    description='ROS-free core of the APF multi-UAV formation tracking swarm.',
    license='Apache-2.0',
    # Executables (if any) go in this one list; they are installed to lib/apf_swarm_core.
    entry_points={
        'console_scripts': [],
    },
)
