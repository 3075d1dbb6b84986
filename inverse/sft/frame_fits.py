"""Shape-from-template on either displacement field through one call: the one reconstructor
(`inverse.sft.reconstruct.FrameReconstructor`) on the field its settings name
(`SplinePriorConfig`: a B-spline field solved by Newton, `inverse.sft.spline_prior`;
`ReconstructionConfig`: a SIREN trained by Adam, `inverse.sft.siren_prior`), looked up in the
inverse registry (`inverse.material.field_types`, the one place in `inverse` that tells field
types apart), run on the one frame-by-frame driver
`inverse.sft.sequential.reconstruct_frames`."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from inverse.material.field_types import of_frame_settings
from inverse.sft.camera import Camera
from inverse.sft.correspondences import FrameCorrespondences
from inverse.sft.flow import DenseFlow
from inverse.sft.guided import GuidedSearch
from inverse.sft.inputs import Template
from inverse.sft.photometric import PhotometricEvidence
from inverse.sft.reconstruct import FrameReconstructor
from inverse.sft.sequential import ReconstructionResult, reconstruct_frames
from inverse.sft.settings import ReconstructionConfig, SplinePriorConfig


def reconstruct_sequence(template: Template, camera: Camera,
                         correspondences: Sequence[FrameCorrespondences],
                         config: SplinePriorConfig | ReconstructionConfig, *,
                         masks: Sequence[np.ndarray] | None = None,
                         pinned: np.ndarray | None = None,
                         initial: Sequence[np.ndarray] | None = None,
                         flow: DenseFlow | None = None,
                         guided: GuidedSearch | None = None,
                         photometric: PhotometricEvidence | None = None,
                         callbacks: Sequence[Any] = ()) -> ReconstructionResult:
    """Vertices [m] for every frame (frame 0 = the template), fitted frame by frame from the
    previous frame on the field that `config` names.

    masks: per-frame silhouettes (bool (h, w)) or None; pinned: vertex indices held at their
    template positions; initial: per-frame guesses (e.g. the baseline's vertices) that a SIREN
    is first fitted to in each frame (ValueError on the spline field, which starts from the
    previous frame's solution); flow: dense-flow correspondences (`inverse.sft.flow`) added to
    each frame's tracks, carried from the frame before's reconstruction; guided: texture
    points re-found where the frames before predict them (`inverse.sft.guided`); photometric:
    the texture compared with each frame (`inverse.sft.photometric`; spline field only); callbacks:
    the solve callbacks of the frame loop (`reconstruct_frames`).
    """
    kind = of_frame_settings(config)
    if photometric is not None and not kind.photometric:
        raise ValueError(f"the photometric term is for the spline field, not the "
                         f"{kind.field_type.name} field")
    fit = FrameReconstructor(template, pinned=pinned, initial=initial, config=config)
    return reconstruct_frames(template, camera, correspondences, fit, masks=masks, flow=flow,
                              guided=guided, photometric=photometric, callbacks=callbacks)
