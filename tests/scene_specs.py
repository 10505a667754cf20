"""Scene specs shared by tests (a sphere on a floor, one point light, direct only)."""

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
