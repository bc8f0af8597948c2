"""The capture rig: protocol, driver, simulator, plans, journal and the capture loop.

* :mod:`.protocol`   the ``usdbtf-rig/1`` line protocol (docs/rig-protocol.md);
* :mod:`.driver`     :class:`~.driver.RigDriver`, the host side over any pyserial port URL;
* :mod:`.kinematics` (view, light) <-> head and arm positions;
* :mod:`.plan`       capture plans: obstruction model and travel-minimising order;
* :mod:`.journal`    the append-only record that makes captures resumable;
* :mod:`.camera`     frame sources (cv2.VideoCapture or a command hook);
* :mod:`.capture`    the capture loop writing a RAW manifest folder;
* :mod:`.scene`, :mod:`.sim`  the simulated camera and controller behind ``usdbtf rig-sim``.
"""

#: Capture orders (:func:`.plan.make_plan`); here so the command line lists them without numpy.
ORDERS = ("travel", "sampling")
