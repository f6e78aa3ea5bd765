"""Classical segmentation, no training: RANSAC planes, density clusters, ground filtering.

=================  ==============================================================
``planes.py``      :func:`segment_planes`: RANSAC planes, largest first, with equations
``clusters.py``    :func:`dbscan`, :func:`clusters_beside_planes`: DBSCAN clusters
``ground.py``      :func:`ground_mask`: the cloth simulation filter (``CSF``)
=================  ==============================================================

Each returns per-point labels that the ``pointfield cloud planes|clusters|ground`` verbs write
back as a field of the cloud.
"""

from pointfield.segmentation.clusters import clusters_beside_planes, dbscan
from pointfield.segmentation.ground import default_cloth_resolution, ground_classification, ground_mask, iou
from pointfield.segmentation.planes import Plane, fit_plane, ransac_plane, segment_planes

__all__ = ["Plane", "clusters_beside_planes", "dbscan", "default_cloth_resolution", "fit_plane", "ground_classification",
           "ground_mask", "iou", "ransac_plane", "segment_planes"]
