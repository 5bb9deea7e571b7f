"""The window's progress bar and status text while an operator works (Blender redraws only between
operators: the status bar is drawn once per stage)."""

import bpy


class Progress:
    """Progress bar and status-bar text during long work: Build Relief, Import Mosaic, Season
    Animation (both may be missing in background mode)."""

    def __init__(self, context):
        self.wm = context.window_manager
        self.workspace = context.workspace

    def __enter__(self):
        self.wm.progress_begin(0, 100)
        return self

    def __call__(self, fraction, stage):
        self.wm.progress_update(int(round(100 * min(max(fraction, 0.0), 1.0))))
        if self.workspace is not None:
            self.workspace.status_text_set(f"Cliff Terrain: {stage} ({fraction:.0%})")
            # The window redraws only between operators: draw the status bar once per stage.
            if stage != getattr(self, "stage", None) and not bpy.app.background:
                self.stage = stage
                bpy.ops.wm.redraw_timer(type="DRAW_WIN_SWAP", iterations=1)

    def __exit__(self, *exc):
        self.wm.progress_end()
        if self.workspace is not None:
            self.workspace.status_text_set(None)
        return False
