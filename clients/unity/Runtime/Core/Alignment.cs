namespace Vista.Client
{
    /// <summary>
    /// Marker-based alignment. The scene (scene.glb) holds a node <c>marker-&lt;name&gt;</c> per
    /// printed image marker: the marker's pose in the scene, <c>scene_T_marker</c>. When the
    /// headset's tracker sees that image at <c>world_T_marker</c> in its own world, the scene
    /// belongs at <c>world_T_scene = world_T_marker × scene_T_marker⁻¹</c>. The math holds in any
    /// one consistent frame convention; both poses must use the same one.
    /// <para>
    /// The anchor node's own axes are the marker's base-frame axes (x right, y up the image,
    /// z out of it) taken through the same Z-up → Y-up change as every pose
    /// (<see cref="BaseToScene(Matrix4)"/>): in the glTF scene the node's x is the image's
    /// right, its y points out of the image and its z to the image's bottom. The tracker's
    /// pose must be that of a frame with these axes.
    /// </para>
    /// </summary>
    public static class Alignment
    {
        /// <summary>Millimetres per metre: vista's base frame is in mm, glTF in m.</summary>
        public const double MillimetresPerMetre = 1000.0;

        /// <summary>Where the scene's origin belongs in the tracker's world, given where the
        /// tracker sees a marker and where that marker sits in the scene.</summary>
        public static Matrix4 WorldFromScene(Pose worldFromMarkerSeen, Pose sceneFromMarker)
        {
            return worldFromMarkerSeen.ToMatrix() * sceneFromMarker.ToMatrix().RigidInverse();
        }

        /// <summary>A point of vista's base frame (mm, +Z up) in glTF scene coordinates
        /// (m, +Y up): (x, y, z) → (x, z, −y) / 1000.</summary>
        public static double[] BaseToScene(double xMm, double yMm, double zMm)
        {
            return new[]
            {
                xMm / MillimetresPerMetre,
                zMm / MillimetresPerMetre,
                -yMm / MillimetresPerMetre,
            };
        }

        /// <summary>A rigid pose of the base frame (mm, e.g. an image marker's
        /// <c>base_T_marker</c>) as a glTF scene pose (m, +Y up): the rotation conjugated by the
        /// axis change, the translation converted like a point. This is where scene.glb puts the
        /// marker's anchor node.</summary>
        public static Pose BaseToScene(Matrix4 baseFromFrame)
        {
            Matrix4 axes = new Matrix4(new double[]
            {
                1, 0, 0, 0,
                0, 0, 1, 0,
                0, -1, 0, 0,
                0, 0, 0, 1,
            });
            Matrix4 rotation = axes * baseFromFrame * axes.RigidInverse();
            double[] position = BaseToScene(baseFromFrame[0, 3], baseFromFrame[1, 3], baseFromFrame[2, 3]);
            Pose turned = Pose.FromMatrix(rotation);
            return new Pose(position[0], position[1], position[2], turned.Qx, turned.Qy, turned.Qz, turned.Qw);
        }
    }
}
