"""Learned masks (mask method "learned"): a small CPU network in place of the hand-made motion-mask chain.

Modules: features (the network's per-pixel inputs from the pipeline's flow evidence, and
LearnedMaskConfig; NumPy and OpenCV only), net (MaskNet, its checkpoint, inference in torch), moving
(the drop-in for `motion.moving_from_motion`), data (the training sources: rendered clips, development
composites, DAVIS development clips; never a validation clip) and train (the recipe of
`moseg train --preset masknet`, which rebuilds mosegpipe/weights/masknet.pt).
"""

MASKNET_PRESET = "masknet"
"""`moseg train --preset` name of the mask network's recipe (`learned.train.MaskTrainConfig`)."""
