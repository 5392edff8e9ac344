"""Point-cloud registration that is pure numerics (numpy, scipy, pykdtree): usable by every plugin.

* :mod:`weldcell.sdk.registration.ndt`: point-to-distribution NDT (Magnusson 2009), multi-resolution,
  with the voxel/point-spacing helpers it derives its resolutions from. Used by map segmentation's
  hand-over (plugins/mapping) and by relocalization (plugins/relocalize).
"""
