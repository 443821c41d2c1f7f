"""Recording layer: runs streamed into rosbag2 (MCAP) bags, and bags read back.

Modules: `columns` and `nve_columns` (the per-tick record schemas of teleoperation and NVE runs and their
topics), `layouts` (message types, topics, fixed CDR layouts), `streams` (tick and packet
encoders), `mcap` (the MCAP file writer), `metadata` (metadata.yaml), `recorder` (RunRecorder and
its writer process), `reader` (BagReader), `tools` (bag info and recover).
"""
