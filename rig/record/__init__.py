"""The run folder: its record, observations, atomic writes, catalogue; written by rig.run, read by everything
above."""
