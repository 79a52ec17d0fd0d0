"""Learned masks (mask method "learned"): a small CPU network in place of the hand-made motion-mask chain.

Modules: features (the network's per-pixel inputs from the pipeline's flow evidence, and
LearnedMaskConfig; NumPy and OpenCV only), net (MaskNet, its checkpoint, inference in torch), moving
(the drop-in for `motion.moving_from_motion`), data (the training sources: rendered clips, development
composites, DAVIS development clips; never a validation clip) and train (the recipe of
`moseg train --preset masknet`, which rebuilds mosegpipe/weights/masknet.pt); which (the per-motion network: which
of a frame's moving motions a moving pixel belongs to, `MaskConfig.which` "learned") and which_train (its recipe,
`moseg train --preset whichnet`, mosegpipe/weights/whichnet.pt).
"""

MASKNET_PRESET = "masknet"
"""`moseg train --preset` name of the mask network's recipe (`learned.train.MaskTrainConfig`)."""

WHICHNET_PRESET = "whichnet"
"""`moseg train --preset` name of the per-motion network's recipe (`learned.which_train.WhichTrainConfig`)."""
