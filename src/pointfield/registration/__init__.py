"""Registration: the rigid motion that maps one scan onto another, and how far to trust it.

One file per piece, as open3d's ``pipelines.registration`` names them:

=============================  ============================================================
``pairwise.py``                :func:`register`, the entry point: checks, voxel, method choice
``icp.py``                     :func:`registration_icp` (numpy reference), small_gicp fast path,
                               :func:`multiscale_icp` (coarse to fine)
``estimation.py``              :class:`PointToPoint`, :class:`PointToPlane`,
                               :class:`GeneralizedICP`, :class:`ColoredICP`
``kernels.py``                 :class:`HuberLoss`, :class:`TukeyLoss` (robust reweighting)
``fpfh.py``                    :func:`compute_fpfh`, Fast Point Feature Histograms
``global_registration.py``     feature matching and RANSAC with correspondence checkers
``result.py``                  :class:`RegistrationResult`, fitness, RMSE, information matrix
``scan.py``                    :class:`Scan`, the arrays the above work on
``pose_graph.py``              :func:`optimize_pose_graph`: poses consistent over every edge, loop closures pruned
``multiway.py``                :func:`align`, many scans into one frame (open3d's multiway registration)
``fragments.py``               :func:`fragment_poses`, RGB-D odometry refined over fragments and loop closures
``streamed.py``                scans read whole or thinned while streaming within ``--memory``; written moved
=============================  ============================================================
"""

from pointfield.registration.estimation import ColoredICP, GeneralizedICP, PointToPlane, PointToPoint, kabsch
from pointfield.registration.fpfh import compute_fpfh
from pointfield.registration.fragments import fragment_poses
from pointfield.registration.global_registration import (
    DistanceChecker,
    EdgeLengthChecker,
    RANSACCriteria,
    match_features,
    ransac_on_matches,
)
from pointfield.registration.icp import (
    ICPConvergenceCriteria,
    multiscale_icp,
    registration_icp,
    registration_small_gicp,
)
from pointfield.registration.kernels import HuberLoss, L2Loss, TukeyLoss
from pointfield.registration.multiway import AlignedPair, AlignResult, align
from pointfield.registration.pairwise import (
    METHODS,
    aligned,
    check_cloud,
    check_transformation,
    default_voxel,
    feature_alignment,
    register,
)
from pointfield.registration.pose_graph import PoseGraph, PoseGraphEdge, optimize_pose_graph
from pointfield.registration.result import RegistrationResult, evaluate, information_matrix
from pointfield.registration.scan import Scan

__all__ = [
    "METHODS", "AlignResult", "AlignedPair", "PoseGraph", "PoseGraphEdge", "align", "optimize_pose_graph", "ColoredICP", "DistanceChecker", "EdgeLengthChecker", "GeneralizedICP", "HuberLoss",
    "ICPConvergenceCriteria", "L2Loss", "PointToPlane", "PointToPoint", "RANSACCriteria", "RegistrationResult",
    "Scan", "TukeyLoss", "aligned", "check_cloud", "check_transformation", "compute_fpfh", "default_voxel",
    "evaluate", "feature_alignment", "fragment_poses", "information_matrix", "kabsch", "match_features",
    "multiscale_icp",
    "ransac_on_matches", "register", "registration_icp", "registration_small_gicp",
]
