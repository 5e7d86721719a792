"""The octree stream, abyss's scene from the vessel to shore, in one place:

- `octree`: OctoMap's octree read and written (binary format, cells by packed key, leaves);
- `cells`: sets of cells (what was published, what is queued);
- `model`: the vessel's octree from the clouds, and what of it shore has (`SceneModel`);
- `stream` and `pacing`: the updates sent, paced by shore's acknowledgements (`SceneStream`);
- `receiver`: shore's copy (`SceneReceiver`) and its core (`ShoreScene`: apply in order,
  acknowledge, ask for a snapshot after a gap);
- `export`: the map a run leaves, written out as OctoMap `.bt` or a `.ply` cloud.

It imports the rooms below it (common, description, interface, timing, config, bus), never the link
emulator.
"""
