"""The two-step learned estimator of Wu, Yilmaz, Kazanzides and Tumerdem (arXiv 2012.01479).

Pure core: arrays in, arrays out; the only file I/O is :mod:`.checkpoint`.

* :mod:`.features`   feature rows ``[q, dq]``, gap segmentation, history windows
* :mod:`.kernels`    NumPy eval-mode kernels for one-sample streaming steps
* :mod:`.free_space` step 1: one LSTM network per joint group (``FreeSpaceModel``; ``Troc``)
* :mod:`.correction` step 2: ``Corr`` (feed-forward correction) and ``Xfer`` (transfer learning)
* :mod:`.wrench`     external torque and the damped inverse-transpose Jacobian map
* :mod:`.estimator`  ``TwoStepEstimator``: streaming ``step_one`` and offline ``predict_batch``
* :mod:`.training`   the paper's training recipes, results and the train/validation split
* :mod:`.free_space_training`  step-1 training (truncated BPTT; also Xfer's loop)
* :mod:`.correction_training`  Xfer and Corr training on a frozen step-1 model
* :mod:`.checkpoint` self-describing checkpoints, loaded with ``weights_only=True``
"""

from wrenchd.models.estimator.correction import Corr, CorrConfig, Xfer, XferConfig
from wrenchd.models.estimator.estimator import (EstimatorBatch, EstimatorConfig, EstimatorOutput,
                                        TwoStepEstimator)
from wrenchd.models.estimator.free_space import FreeSpaceConfig, FreeSpaceModel
from wrenchd.models.estimator.wrench import WrenchMap, WrenchMapConfig

__all__ = [
    "Corr", "CorrConfig", "EstimatorBatch", "EstimatorConfig", "EstimatorOutput",
    "FreeSpaceConfig", "FreeSpaceModel", "TwoStepEstimator", "WrenchMap", "WrenchMapConfig",
    "Xfer", "XferConfig",
]
