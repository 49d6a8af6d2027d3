"""What several operators share: the Object Mode poll, the image output options, selecting
what an Add operator made."""
from bpy.props import BoolProperty


class ObjectModeOperator:
    """Mixin: runs in Object Mode only, and says so on the greyed-out button."""
    poll_mode_message = "Only in Object Mode"

    @classmethod
    def poll(cls, context):
        if context.scene is None or context.mode != "OBJECT":
            cls.poll_message_set(cls.poll_mode_message)
            return False
        return True


class ImageOutputOptions:
    """Mixin: where baked images go (annotations on a mixin are registered with the operator,
    as bpy_extras.io_utils.ImportHelper's are)."""
    overwrite: BoolProperty(
        name="Overwrite Images", default=False,
        description="Replace existing images of the same name that this add-on did not make; "
                    "off: such images are kept and the bake writes to a new name")
    pack: BoolProperty(
        name="Pack Images", default=False,
        description="Pack the images into the .blend instead of saving them to //lightmaps/")


def select_only(context, ob):
    """Makes `ob` the only selected and the active object, as Blender's Add operators do."""
    for other in context.selected_objects:
        if other != ob:
            other.select_set(False)
    ob.select_set(True)
    context.view_layer.objects.active = ob
