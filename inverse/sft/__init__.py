"""Monocular shape-from-template: recover a deforming sheet's 3D surface in every video frame.

Modules, in pipeline order (conventions and the evaluation protocol: ``docs/sft.md``):
``inputs`` (input contract, loading, validation), ``surface`` (template surface points as
(face, barycentric)), ``tracking`` (texture registration and Lucas–Kanade tracks),
``baseline`` (per-frame reprojection + inextensibility + smoothness least squares),
``sequential`` with ``least_squares`` and ``silhouette`` (the physics-regularised
reconstruction frame by frame, with its one data term, for either field; ``frame_fits``:
``reconstruct_sequence``, the one entry, the field named by its settings), ``spline_prior`` (a
spline field by Gauss–Newton, the default) and ``siren_prior`` (a SIREN field by Adam), both
run by ``reconstruct`` (the one reconstructor),
``metrics`` (e3D, chamfer, normal
and reprojection errors), ``chamfer`` (the field's protocol against point clouds); input
checks before any work: ``input_checks`` (template, UVs, clouds against frame 0) and ``limits``
(image sizes from headers against memory); real captures: ``capture`` (the φ-SfT / PGSfT
layout); synthetic data with ground truth: ``texture``, ``deformations``, ``degradations``,
``synth``.
"""
