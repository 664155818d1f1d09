"""Recognition (Galileo section 4): physical properties seen in one frame, learnt from the
model's own inferences, and used to start MCMC near the answer.

* `data`: a rendered dataset as examples (which object, which video, which object and group
  a split keeps together), Galileo labels (`make_labels`: MCMC on every video), object
  splits, the trackers' crops (`patches`).
* `lenet`: LeNet-5 on 3 x 32 x 32 patches -> a Gaussian over (log-normalised mass, friction);
  an ensemble of such networks.
* `model`: a trained model (`LeNetModel`), its file, its readings of a video (`Reading`),
  chain starts and the independence proposal from them (`recognition_init`).
* `simulation`: the second model, trained on simulations from the prior (no labels): the
  tracked velocity series in, every latent out; any scenario.
* `train`: training on a dataset and the paper's Fig. 3 table over object-held-out splits.
* `modelfile`: model files (NPZ + JSON header; never pickle).
"""
