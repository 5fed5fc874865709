"""The middleware under the nodes: Fast DDS profiles and isolation, the secure transport,
QoS, shared-memory files and their cleanup."""
