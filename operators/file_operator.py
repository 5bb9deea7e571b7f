"""A mixin for the operators that start from a file or folder the user picks."""


class FileOperator:
    """Runs in Object Mode only; invoked without a path, it opens the file browser first.

    `path_property` names the operator's path property (a FILE_PATH or DIR_PATH StringProperty).
    """

    path_property = "filepath"

    @classmethod
    def poll(cls, context):
        return context.mode == "OBJECT"

    def invoke(self, context, event):
        if not getattr(self, self.path_property):
            context.window_manager.fileselect_add(self)
            return {"RUNNING_MODAL"}
        return self.execute(context)
