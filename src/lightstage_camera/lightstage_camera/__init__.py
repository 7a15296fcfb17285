"""Camera hardware and acquisition: the camera node and its backends, and the acquisition
node (model capture, noise calibration). The physics it renders and records is
lightstage_physics'.

Camera backends (no rclpy; docs/CAMERAS.md):
    camera_backend       what the camera node needs from a camera: triggers in, stamped frames out
    sim_camera           the simulated camera: the sample on the stage relit by a trigger's LEDs
    triggered_backend    a real, triggered camera: a worker thread that opens, sets, fires, grabs
    trigger_pairing      grabbed frames paired with the triggers that caused them, never guessed
    basler_backend       Basler cameras through pypylon
    aravis_backend       GenICam cameras (GigE Vision, USB3 Vision) through Aravis
    camera_info          camera calibration for camera_info (camera_info_manager's YAML)
Acquisition on the stage (no rclpy):
    acquisition          model capture: one averaged image per single LED into a capture folder
    capture_settings     what one model capture asks of the stage
    capture_destination  writing one pose into a capture folder (names, rig.yaml, atomic writes)
    calibration          noise calibration: a target lit at increasing levels, the noise fit
    calibration_outputs  the files of a noise calibration: the noise file and its plot
    rescue               what a capture could not write, kept to write later
ROS (rclpy):
    camera_node          one camera/image_raw frame per light-stage trigger, stamped with it
    acquisition_node     model capture and noise calibration as actions

Importing the package imports none of them; a camera SDK (pypylon, Aravis) loads only when its
backend first talks to a camera.
"""

__all__ = ['camera_backend', 'sim_camera', 'triggered_backend', 'trigger_pairing',
           'basler_backend', 'aravis_backend', 'camera_info', 'acquisition', 'capture_settings',
           'capture_destination', 'calibration', 'calibration_outputs', 'rescue', 'camera_node',
           'acquisition_node']
