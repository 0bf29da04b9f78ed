"""The modes a scene chooses among and the limits of one frame, which the scene
model (exabricks.scene.model) and the option table (exabricks.scene.options)
both read."""

SHADING_MODES = ("headlight", "none")
# How light reaches a sample (docs/design-rendering.md, "Lights and shadows"): the
# camera's headlight (shaded by --shading), a directional light with the
# volume's shadows and an ambient term, or volumetric path tracing of the same
# lights with multiple scattering.
INTEGRATORS = ("headlight", "shadow", "path")
# The shadow integrator's transmittance toward the light: cached once per light in
# a light-space volume (exabricks.engine.light_volume), or traced from every sample.
SHADOW_RAYS = ("cached", "traced")
GRADIENTS = ("analytic", "central")
# How a point's value comes from the cells (docs/design-rendering.md, "Reconstructions: basis, nearest,
# vertex").
RECONSTRUCTIONS = ("basis", "nearest", "vertex")
# How a volume layer's transfer function is read per sample (docs/design-rendering.md,
# "Transfer-function tables"): from a lookup table, or from its knots.
TF_LOOKUPS = ("table", "exact")

# Limits of one frame (the kernels keep these in private arrays).
MAX_VOLUMES = 8
MAX_ISOSURFACES = 32
MAX_SLICES = 8
MAX_CLIP_PLANES = 16
MAX_AO_SAMPLES = 256
# Scattering events of one path of the path integrator.
MAX_BOUNCES = 256
MAX_MESHES = 16
# Instances besides the identity (exabricks.engine.instances).
MAX_INSTANCES = 7
AXES = ("x", "y", "z")
# Mesh hits a ray composites, the nearest (kernels/mesh.cl).
MAX_MESH_HITS = 8
