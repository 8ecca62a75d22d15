"""The neural-network layer every learned service shares (odometry, depth, tracking)."""
