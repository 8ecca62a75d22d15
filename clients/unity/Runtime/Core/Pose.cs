using System;

namespace Vista.Client
{
    /// <summary>A rigid pose: a position (metres) and a unit rotation quaternion (x, y, z, w),
    /// the way glTF nodes and AR trackers give them.</summary>
    public struct Pose
    {
        /// <summary>Position along x.</summary>
        public readonly double X;
        /// <summary>Position along y.</summary>
        public readonly double Y;
        /// <summary>Position along z.</summary>
        public readonly double Z;
        /// <summary>Rotation quaternion, x part.</summary>
        public readonly double Qx;
        /// <summary>Rotation quaternion, y part.</summary>
        public readonly double Qy;
        /// <summary>Rotation quaternion, z part.</summary>
        public readonly double Qz;
        /// <summary>Rotation quaternion, w (scalar) part.</summary>
        public readonly double Qw;

        /// <summary>A pose from a position and a rotation quaternion (normalised here).</summary>
        public Pose(double x, double y, double z, double qx, double qy, double qz, double qw)
        {
            double norm = Math.Sqrt(qx * qx + qy * qy + qz * qz + qw * qw);
            if (norm < 1e-12 || double.IsNaN(norm))
            {
                throw new ArgumentException("the rotation quaternion has no length");
            }
            X = x;
            Y = y;
            Z = z;
            Qx = qx / norm;
            Qy = qy / norm;
            Qz = qz / norm;
            Qw = qw / norm;
        }

        /// <summary>A pose from glTF's <c>translation</c> and <c>rotation</c> (xyzw) arrays;
        /// either may be null (zero, identity).</summary>
        public static Pose FromGltf(double[] translation, double[] rotationXyzw)
        {
            double[] t = translation ?? new double[3];
            double[] q = rotationXyzw ?? new double[] { 0, 0, 0, 1 };
            if (t.Length != 3 || q.Length != 4)
            {
                throw new ArgumentException("a glTF translation has 3 numbers and a rotation 4");
            }
            return new Pose(t[0], t[1], t[2], q[0], q[1], q[2], q[3]);
        }

        /// <summary>The pose as a 4 × 4 rigid transform.</summary>
        public Matrix4 ToMatrix()
        {
            double x = Qx, y = Qy, z = Qz, w = Qw;
            return new Matrix4(new double[]
            {
                1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w), X,
                2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w), Y,
                2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y), Z,
                0, 0, 0, 1,
            });
        }

        /// <summary>The pose of a transform: its translation and the rotation of its 3 × 3 part
        /// with any scale divided out of the columns (Shepperd's method, w ≥ 0).</summary>
        public static Pose FromMatrix(Matrix4 matrix)
        {
            var m = new double[3, 3];
            for (int c = 0; c < 3; c++)
            {
                double length = Math.Sqrt(matrix[0, c] * matrix[0, c] + matrix[1, c] * matrix[1, c]
                    + matrix[2, c] * matrix[2, c]);
                if (length < 1e-12)
                {
                    throw new ArgumentException("the matrix has a zero column: no rotation");
                }
                for (int r = 0; r < 3; r++)
                {
                    m[r, c] = matrix[r, c] / length;
                }
            }
            double trace = m[0, 0] + m[1, 1] + m[2, 2];
            double qx, qy, qz, qw;
            if (trace >= m[0, 0] && trace >= m[1, 1] && trace >= m[2, 2])
            {
                double s = 2 * Math.Sqrt(1 + trace);
                qx = (m[2, 1] - m[1, 2]) / s;
                qy = (m[0, 2] - m[2, 0]) / s;
                qz = (m[1, 0] - m[0, 1]) / s;
                qw = s / 4;
            }
            else if (m[0, 0] >= m[1, 1] && m[0, 0] >= m[2, 2])
            {
                double s = 2 * Math.Sqrt(1 + m[0, 0] - m[1, 1] - m[2, 2]);
                qx = s / 4;
                qy = (m[0, 1] + m[1, 0]) / s;
                qz = (m[0, 2] + m[2, 0]) / s;
                qw = (m[2, 1] - m[1, 2]) / s;
            }
            else if (m[1, 1] >= m[2, 2])
            {
                double s = 2 * Math.Sqrt(1 + m[1, 1] - m[0, 0] - m[2, 2]);
                qx = (m[0, 1] + m[1, 0]) / s;
                qy = s / 4;
                qz = (m[1, 2] + m[2, 1]) / s;
                qw = (m[0, 2] - m[2, 0]) / s;
            }
            else
            {
                double s = 2 * Math.Sqrt(1 + m[2, 2] - m[0, 0] - m[1, 1]);
                qx = (m[0, 2] + m[2, 0]) / s;
                qy = (m[1, 2] + m[2, 1]) / s;
                qz = s / 4;
                qw = (m[1, 0] - m[0, 1]) / s;
            }
            double sign = qw < 0 ? -1 : 1;
            return new Pose(matrix[0, 3], matrix[1, 3], matrix[2, 3],
                sign * qx, sign * qy, sign * qz, sign * qw);
        }
    }
}
