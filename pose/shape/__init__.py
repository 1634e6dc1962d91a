"""Shape recognition from binary silhouettes.

* :mod:`pose.shape.descriptors`: Fourier (32) + MPEG-7 ART (35) + affine moment invariants (6)
  -> :func:`~pose.shape.descriptors.shape_descriptor`, a 73-vector.
* :mod:`pose.shape.flr`: the Fuzzy Lattice Reasoning classifier on Intervals' Numbers.
* :mod:`pose.shape.baselines`: k-NN and SVM pipelines on the same descriptors.
* :mod:`pose.shape.datasets`: MPEG-7 CE-Shape-1 and ETH-80 loaders.
* :mod:`pose.shape.silhouettes`: synthetic silhouettes drawn with OpenCV.
* :mod:`pose.shape.evaluation`: held-out comparison, JSON and confusion-matrix PNG.
"""
