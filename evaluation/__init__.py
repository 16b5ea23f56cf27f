"""Evaluation of monoflow: scene-flow test-set readers, community metrics, ICP/FGR baselines, reports, ablations.

Core modules: :mod:`evaluation.sample` (the test sample), :mod:`evaluation.readers` (FlowNet3D /
HPLFlowNet / OpenSceneFlow test sets, one module per format behind one registry,
:func:`~evaluation.readers.load_split`; their axis conventions are :mod:`core.axes`),
:mod:`evaluation.metrics` (EPE3D, Acc3DS/R, Outliers3D, three-way and dynamic normalised EPE, distance
bands), :mod:`evaluation.protocols` (which points are scored) and
:mod:`evaluation.scenes` (HPLFlowNet's mapping, --scenes, the trained-on guard),
:mod:`evaluation.baselines` (zero, static pose, ICP, FGR) and :mod:`evaluation.predictions` (saved
predictions, one HDF5 file). Nothing heavy is imported here.
"""
