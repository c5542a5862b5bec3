"""Device drivers of the physical rig: the ``PanTilt`` interface and its driver
registry (:mod:`.pan_tilt`), the PTU-D46 driver (:mod:`.ptu`), cameras
(:mod:`.camera`, OpenCV), and the motion controller's datagram codec
(:mod:`.datagram`) and UDP client (:mod:`.udp_link`).  Each module imports its
own library (pyserial, OpenCV) only when it is imported itself."""
