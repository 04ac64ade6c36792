"""The application around the method (not what the paper describes): fitting and sampling runs, their folders
and files, shipped models, the checks of user values, and the device and thread policy."""
