"""Demonstration datasets in the project's schema (:mod:`lerobot_actionflow.schema`).

- :mod:`.collect`: scripted-expert rollouts into a LeRobotDataset (``actionflow-collect``).
- :mod:`.convert`: robomimic / mimicgen HDF5 files into a LeRobotDataset (``actionflow-convert``),
  from :mod:`.robomimic` (the file layout, read and checked) and :mod:`.schema_arrays` (the
  frames and maths that turn a demo into the schema's arrays).
- :mod:`.features`: the LeRobot feature spec and the observation -> frame mapping both share.
"""
