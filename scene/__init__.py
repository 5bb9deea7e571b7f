"""What the operators put into a Blender scene, none of it an operator: the relief's mesh
(``mesh_data``), material (``material``) and object, with the removal of what a failed build
made (``datablocks``), and for the rendered figures the view rig of cameras
and light (``rig``), the render materials (``render_materials``), the render settings
(``render_settings``) and the views themselves (``views``).

Nothing here registers classes; the operators and ``render_views.py`` call these functions.
"""
