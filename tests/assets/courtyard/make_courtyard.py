# The courtyard scene, exported by Blender's own glTF 2.0 exporter (Debian 12's `blender`, 3.4):
#   blender -b --factory-startup --python make_courtyard.py
# Every material is Blender's Principled BSDF with image maps, which the exporter writes as glTF's
# metallic-roughness materials with all their maps:
# - "paving": stone tiles repeating 3 x 3 times over the floor, a tangent-space normal map of
#   their bevels and grooves, roughness from a map, ambient occlusion in the grooves (through the
#   exporter's "glTF Settings" node group, its way of writing occlusionTexture);
# - "brass": a smooth sphere (vertex normals), metallic, its roughness from a map of streaks;
# - "lamp": a sign whose letters glow (an emissive map), on a plain painted board.
# The textures are computed here with numpy (height fields and their gradients) and written as
# PNG by Blender beside this script; the GLB holds copies of them (export_image_format AUTO).
import math
import os

import bpy
import numpy as np

here = os.path.dirname(os.path.abspath(__file__))
bpy.ops.wm.read_factory_settings(use_empty=True)
N = 256
rng = np.random.default_rng(5)


def smooth_noise(cells, seed):
    """Bilinear value noise, `cells` cells per side, values in [0, 1]."""
    g = np.random.default_rng(seed).random((cells + 1, cells + 1))
    x = np.linspace(0, cells, N, endpoint=False)
    i = x.astype(int)
    f = x - i
    a = g[i][:, i] * (1 - f)[None, :] + g[i][:, i + 1] * f[None, :]
    b = g[i + 1][:, i] * (1 - f)[None, :] + g[i + 1][:, i + 1] * f[None, :]
    return a * (1 - f)[:, None] + b * f[:, None]


def save(name, rgba, colour):
    """rgba: N x N x 4 floats in [0, 1], rows top to bottom."""
    img = bpy.data.images.new(name, N, N, alpha=True)
    img.colorspace_settings.name = "sRGB" if colour else "Non-Color"
    img.pixels.foreach_set(np.ascontiguousarray(np.clip(rgba[::-1], 0, 1), dtype=np.float32).ravel())
    img.filepath_raw = os.path.join(here, name + ".png")
    img.file_format = "PNG"
    img.save()
    return img


def normals_from_height(h, strength):
    """A tangent-space normal map (OpenGL's +Y up, as glTF's) of height field h (rows top down)."""
    dx = (np.roll(h, -1, axis=1) - np.roll(h, 1, axis=1)) * 0.5 * strength
    dy = (np.roll(h, 1, axis=0) - np.roll(h, -1, axis=0)) * 0.5 * strength  # up the image
    n = np.stack([-dx, -dy, np.ones_like(h)], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return np.concatenate([n * 0.5 + 0.5, np.ones((N, N, 1))], axis=-1)


def rgba(r, g, b, a=None):
    return np.stack([r, g, b, np.ones_like(r) if a is None else a], axis=-1)


# Paving: 4 x 4 tiles per texture, grooves between them, bevelled edges, speckled stone.
u = (np.arange(N) + 0.5) / N * 4
fx = u - np.floor(u)
edge = np.minimum(np.minimum(fx[None, :], 1 - fx[None, :]), np.minimum(fx[:, None], 1 - fx[:, None]))
stone = smooth_noise(16, 1) * 0.6 + smooth_noise(64, 2) * 0.4
height = np.clip(edge / 0.08, 0, 1) * 0.8 + stone * 0.2
tile_tint = np.kron(rng.random((4, 4)), np.ones((N // 4, N // 4)))
base = 0.35 + 0.25 * stone + 0.15 * tile_tint
groove = np.clip(edge / 0.08, 0, 1)
paving_colour = save("paving_colour", rgba(base * 0.95 * (0.5 + 0.5 * groove), base * 0.85 * (0.5 + 0.5 * groove), base * 0.7 * (0.5 + 0.5 * groove)), True)
paving_normal = save("paving_normal", normals_from_height(height, 24.0), False)
rough = 0.55 + 0.4 * smooth_noise(32, 3)
paving_rm = save("paving_roughness_metallic", rgba(np.zeros((N, N)), rough, np.zeros((N, N))), False)
ao = 0.35 + 0.65 * np.clip(edge / 0.12, 0, 1)
paving_ao = save("paving_occlusion", rgba(ao, ao, ao), False)

# Brass: metallic everywhere, streaks of roughness.
streak = smooth_noise(8, 4)[:, :1].repeat(N, axis=1) * 0.5 + smooth_noise(48, 5) * 0.5
brass_colour = save("brass_colour", rgba(np.full((N, N), 0.85), np.full((N, N), 0.62), np.full((N, N), 0.28)), True)
brass_rm = save("brass_roughness_metallic", rgba(np.zeros((N, N)), 0.15 + 0.5 * streak, np.ones((N, N))), False)

# Lamp: a board with glowing bars (the letters of a sign, roughly), emissive where they are.
yy, xx = np.mgrid[0:N, 0:N] / N
bars = ((np.abs(((xx * 6) % 1) - 0.5) < 0.18) & (np.abs(yy - 0.5) < 0.3)).astype(float)
lamp_colour = save("lamp_colour", rgba(0.15 + 0.1 * bars, 0.2 + 0.1 * bars, 0.35 - 0.1 * bars), True)
glow = bars * (0.6 + 0.4 * smooth_noise(12, 6))
lamp_emissive = save("lamp_emissive", rgba(glow, glow * 0.75, glow * 0.3), True)


def image_node(mat, img, location):
    t = mat.node_tree.nodes.new("ShaderNodeTexImage")
    t.image = img
    t.location = location
    return t


def occlusion_group():
    # The exporter writes occlusionTexture from a node group named "glTF Settings" whose input
    # "Occlusion" is linked to an image's red channel.
    g = bpy.data.node_groups.new("glTF Settings", "ShaderNodeTree")
    g.inputs.new("NodeSocketFloat", "Occlusion")
    return g


def material(name, colour, normal=None, rm=None, ao=None, emissive=None, metallic=0.0, roughness=0.5):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nt = mat.node_tree
    bsdf = nt.nodes["Principled BSDF"]
    nt.links.new(image_node(mat, colour, (-600, 300)).outputs["Color"], bsdf.inputs["Base Color"])
    bsdf.inputs["Metallic"].default_value = metallic
    bsdf.inputs["Roughness"].default_value = roughness
    if normal:
        nm = nt.nodes.new("ShaderNodeNormalMap")
        nt.links.new(image_node(mat, normal, (-600, -300)).outputs["Color"], nm.inputs["Color"])
        nt.links.new(nm.outputs["Normal"], bsdf.inputs["Normal"])
    if rm:
        sep = nt.nodes.new("ShaderNodeSeparateColor")
        nt.links.new(image_node(mat, rm, (-800, 0)).outputs["Color"], sep.inputs["Color"])
        nt.links.new(sep.outputs["Green"], bsdf.inputs["Roughness"])
        nt.links.new(sep.outputs["Blue"], bsdf.inputs["Metallic"])
    if ao:
        grp = nt.nodes.new("ShaderNodeGroup")
        grp.node_tree = bpy.data.node_groups.get("glTF Settings") or occlusion_group()
        sep = nt.nodes.new("ShaderNodeSeparateColor")
        nt.links.new(image_node(mat, ao, (-800, -500)).outputs["Color"], sep.inputs["Color"])
        nt.links.new(sep.outputs["Red"], grp.inputs["Occlusion"])
    if emissive:
        nt.links.new(image_node(mat, emissive, (-600, -700)).outputs["Color"], bsdf.inputs["Emission"])
        bsdf.inputs["Emission Strength"].default_value = 1.0
    return mat


paving = material("paving", paving_colour, normal=paving_normal, rm=paving_rm, ao=paving_ao)
brass = material("brass", brass_colour, rm=brass_rm, metallic=1.0)
lamp = material("lamp", lamp_colour, emissive=lamp_emissive, roughness=0.7)

# The floor: 12 x 12 units, the paving repeating 3 x 3 times.
mesh = bpy.data.meshes.new("floor")
mesh.from_pydata([(-6, -6, 0), (6, -6, 0), (6, 6, 0), (-6, 6, 0)], [], [(0, 1, 2, 3)])
uvl = mesh.uv_layers.new(name="UVMap")
for loop in mesh.loops:
    uvl.data[loop.index].uv = [(0, 0), (3, 0), (3, 3), (0, 3)][loop.vertex_index]
mesh.materials.append(paving)
floor = bpy.data.objects.new("floor", mesh)
bpy.context.scene.collection.objects.link(floor)

# A brass sphere, smooth shaded (the exporter writes its vertex normals).
bpy.ops.mesh.primitive_uv_sphere_add(segments=24, ring_count=12, radius=1.2, location=(1.5, 1.0, 1.2))
ball = bpy.context.active_object
ball.name = "ball"
bpy.ops.object.shade_smooth()
ball.data.materials.append(brass)

# A paved plinth under the lamp: a box (hard edges: a normal per face).
bpy.ops.mesh.primitive_cube_add(size=1.0, location=(-2.5, -1.0, 0.5))
plinth = bpy.context.active_object
plinth.name = "plinth"
plinth.scale = (2.0, 1.0, 1.0)
bpy.ops.object.transform_apply(scale=True)
plinth.data.materials.append(paving)

# The lamp's sign, standing on the plinth, facing the scene's front.
mesh = bpy.data.meshes.new("sign")
mesh.from_pydata([(-1.5, 0, 0), (1.5, 0, 0), (1.5, 0, 1.5), (-1.5, 0, 1.5)], [], [(0, 1, 2, 3)])
uvl = mesh.uv_layers.new(name="UVMap")
for loop in mesh.loops:
    uvl.data[loop.index].uv = [(0, 0), (1, 0), (1, 1), (0, 1)][loop.vertex_index]
mesh.materials.append(lamp)
sign = bpy.data.objects.new("sign", mesh)
sign.location = (-2.5, -1.0, 1.0)
sign.rotation_euler = (0.0, 0.0, math.radians(180))
bpy.context.scene.collection.objects.link(sign)

bpy.ops.export_scene.gltf(filepath=os.path.join(here, "courtyard.glb"), export_format="GLB", export_yup=True,
                          export_apply=True, export_image_format="AUTO")
