"""Speed and accuracy benchmarks against the peer libraries (``spherebot-bench`` runs throughput.py)."""
