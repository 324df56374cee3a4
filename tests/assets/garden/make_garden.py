# The garden scene, exported by Blender's own glTF 2.0 exporter (Debian 12's `blender`, 3.4):
#   ./make_textures.sh && blender -b --factory-startup --python make_garden.py
# A lawn (opaque, its texture repeating 4 x 4 times), a lattice fence of three panels (the
# lattice repeating 3 times along each) and a hedge of two crossed cards: the fence and the hedge
# are cut-outs, Blender's "Alpha Clip" at 0.5, which the exporter writes as alphaMode MASK with
# alphaCutoff 0.5. Objects carry their own translations and rotations (the node tree).
import math
import os
import bpy

here = os.path.dirname(os.path.abspath(__file__))
bpy.ops.wm.read_factory_settings(use_empty=True)


def material(name, image, cutout):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes = mat.node_tree.nodes
    bsdf = nodes["Principled BSDF"]
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = bpy.data.images.load(os.path.join(here, image))
    mat.node_tree.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    bsdf.inputs["Roughness"].default_value = 0.8
    if cutout:
        mat.node_tree.links.new(tex.outputs["Alpha"], bsdf.inputs["Alpha"])
        mat.blend_method = "CLIP"
        mat.alpha_threshold = 0.5
        mat.use_backface_culling = False
    return mat


def quad(name, corners, uvs, mat, location=(0, 0, 0), rotation_z=0.0):
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(corners, [], [(0, 1, 2, 3)])
    layer = mesh.uv_layers.new(name="UVMap")
    for loop in mesh.loops:
        layer.data[loop.index].uv = uvs[loop.vertex_index]
    mesh.materials.append(mat)
    obj = bpy.data.objects.new(name, mesh)
    obj.location = location
    obj.rotation_euler = (0.0, 0.0, rotation_z)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def card(name, width, height, repeat, mat, location, rotation_z):
    w = width / 2
    return quad(name, [(-w, 0, 0), (w, 0, 0), (w, 0, height), (-w, 0, height)],
                [(0, 0), (repeat, 0), (repeat, 1), (0, 1)], mat, location, rotation_z)


lawn = material("lawn", "lawn.png", cutout=False)
fence = material("fence", "fence.png", cutout=True)
hedge = material("hedge", "hedge.png", cutout=True)

quad("lawn", [(-8, -8, 0), (8, -8, 0), (8, 8, 0), (-8, 8, 0)], [(0, 0), (4, 0), (4, 4), (0, 4)], lawn)
card("fence_south", 6, 2, 3, fence, (0, -4, 0), 0.0)
card("fence_east", 6, 2, 3, fence, (4, -0.5, 0), math.radians(90))
card("fence_corner", 6, 2, 3, fence, (-4.5, -2, 0), math.radians(-35))
card("hedge_a", 4, 2.5, 1, hedge, (-2, 3, 0), math.radians(20))
card("hedge_b", 4, 2.5, 1, hedge, (-2, 3, 0), math.radians(110))

bpy.ops.export_scene.gltf(filepath=os.path.join(here, "garden.glb"), export_format="GLB", export_yup=True,
                          export_apply=True, export_image_format="AUTO")
