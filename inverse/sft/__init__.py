"""Monocular shape-from-template: recover a deforming sheet's 3D surface in every video frame.

Modules, in pipeline order (conventions and the evaluation protocol: ``docs/sft.md``):
``inputs`` (input contract, loading, validation), ``surface`` (template surface points as
(face, barycentric)), ``tracking`` (texture registration and Lucas–Kanade tracks),
``baseline`` (per-frame reprojection + inextensibility + smoothness least squares),
``spline_prior`` with ``least_squares`` (the physics-regularised reconstruction: a spline
field per frame by Gauss–Newton, the default), ``reconstruct`` with ``data_terms`` (the same
with a SIREN field and Adam), ``metrics`` (e3D, chamfer, normal
and reprojection errors), ``chamfer`` (the field's protocol against point clouds); input
checks before any work: ``input_checks`` (template, UVs, clouds against frame 0) and ``limits``
(image sizes from headers against memory); real captures: ``capture`` (the φ-SfT / PGSfT
layout); synthetic data with ground truth: ``texture``, ``deformations``, ``degradations``,
``synth``.
"""
