"""The great-circle scan model of whisk-broom satellite images fitted to control points: one image (Gauss-Newton
or the 1985 Appendix C search), many images at once (vmap), and the AFFINE touch-up of source 001."""
