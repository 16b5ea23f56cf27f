"""``monoflow-predict``: scene flow for one's own frames (KITTI sequence folder, image folder or video).

See :mod:`evaluation.predict.run` for what is computed and :mod:`evaluation.predict.cli` for the command.
"""
