"""Scene specs shared by tests: a sphere on a floor under one point light (direct only), and a
thin-lens scene in which colour and every feature vary inside a pixel."""

BALL_SCENE = """
name = "{name}"
effects = ["direct"]
[camera]
origin = [0, 1, 4]
target = [0, 0.5, 0]
[[objects]]
shape = "rectangle"
transform = {{ rotate = [-90, 0, 0], scale = [3, 3, 1] }}
[[objects]]
shape = "sphere"
center = [0, 0.5, 0]
radius = 0.5
material = {{ type = "diffuse", reflectance = [0.7, 0.3, 0.2] }}
[[lights]]
type = "point"
position = [1, 3, 2]
intensity = [20, 20, 20]
"""

# Thin lens focused on the middle sphere, textured floor: every feature varies inside a pixel
# (defocus, texture edges, silhouettes), which the variance and half-buffer tests need.
DOF_SCENE = """
name = "dof"
effects = ["direct", "dof"]
[camera]
type = "thinlens"
origin = [0, 1.2, 4.5]
target = [0, 0.45, 0]
fov = 40
aperture_radius = 0.15
[[objects]]
shape = "rectangle"
transform = { rotate = [-90, 0, 0], scale = [6, 6, 1] }
material = { type = "diffuse", reflectance = { checkerboard = { color0 = [0.1, 0.1, 0.1], color1 = [0.8, 0.8, 0.8], scale = 12 } } }
[[objects]]
shape = "sphere"
center = [-0.9, 0.45, 2.0]
radius = 0.45
material = { type = "diffuse", reflectance = { checkerboard = { color0 = [0.9, 0.7, 0.1], color1 = [0.1, 0.2, 0.6], scale = 8 } } }
[[objects]]
shape = "sphere"
center = [0.5, 0.45, 0]
radius = 0.45
[[lights]]
type = "constant"
radiance = [0.6, 0.6, 0.6]
[[lights]]
type = "point"
position = [2, 4, 3]
intensity = [30, 30, 30]
"""
