"""Reference trajectories of the LiDAR for the reward (plugin group ``l2calib.references``).

Built-in sources (see ``docs/references.md``): ``kiss-icp`` (:mod:`.kiss_icp_source`, on
:mod:`.kiss_icp_runner`), ``gt-file`` (:mod:`.gt_file_source`, checked by :mod:`.imu_check`) and
``rtk`` (:mod:`.rtk_source`, :mod:`.geodesy`); options in :mod:`.options`, plugin specs in
:mod:`.specs`, the on-disk cache in :mod:`.cache`.
"""
