"""Vision: pixels -> object poses, one module per job, for any scenario.

* `background`: MOG2 background models, foreground masks, the sensor-noise estimate, mask
  cleaning, resolution changes and connected components (blobs); the working scale and the
  frames a model learns from that bound memory for any video, and frames that show
  something else than the scene.
* `silhouette`: a 3-D shape at a pose projected into a filled image mask, the IoU loss
  against an observed silhouette, and fits of shape and pose to it (Nelder-Mead).
* `klt`: good features inside a silhouette, the KLT window that fits it, pyramidal
  Lucas-Kanade flow from a predicted position with a forward-backward check.
* `pose`: rotation about y, rays cast into the shape, the planar pose (centre in the
  fall-line plane, rotation about y) by Gauss-Newton with iterative outlier rejection.
* `tracker`: one object's features, their 3-D points on the object and its pose per frame.
* `velocity`: velocities from positions (central differences that keep a jump sharp).
* `stabilise`: a video registered to its first frame (camera shake) and normalised to its
  brightness (exposure, flicker, white balance), frames that do not show the scene, the
  noise of registered frames and their blur.
* `shapenet`: the shape-type CNN and the appearance crop it reads.
* `patch`: scale-normalised object patches (a square of fixed metres) for the recognition model.
* `draw`: tracks drawn over frames (debug videos).

A scenario's tracking (e.g. `galileo.scenarios.ramp.tracking`) puts these together; only
this package imports OpenCV.
"""

MAD_TO_SD = 1.4826  # median absolute deviation -> standard deviation of a normal
