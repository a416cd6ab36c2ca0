"""Files at the edges: RGB-D sequences, camera trajectories, label maps, atomic writes, the output folder."""
