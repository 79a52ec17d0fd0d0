"""Learned masks (mask method "learned"): a small CPU network in place of the hand-made motion-mask chain.

Modules: features (the network's per-pixel inputs from the pipeline's flow evidence, and LearnedMaskConfig;
NumPy and OpenCV only), net (MaskNet, its checkpoint, inference in torch), probability (the drop-in for
`moving_pixels.moving_from_motion`), which (the per-motion network: which of a frame's moving motions a moving
pixel belongs to, `MaskConfig.which` "learned"). Their trainers are in `mosegpipe.training.masks`.
"""
