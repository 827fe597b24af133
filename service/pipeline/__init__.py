"""The per-sample pipeline that the daemon and replay both drive."""
