using System;
using System.Collections.Generic;

namespace Vista.Client
{
    /// <summary>An immutable 4 × 4 matrix of doubles, row-major: points are column vectors,
    /// so <c>a_T_c = a_T_b * b_T_c</c> and the translation is the last column.</summary>
    public sealed class Matrix4
    {
        readonly double[] elements;

        /// <summary>A matrix from its 16 elements, row by row.</summary>
        public Matrix4(double[] rowMajor)
        {
            if (rowMajor == null || rowMajor.Length != 16)
            {
                throw new ArgumentException("a 4 × 4 matrix has 16 elements");
            }
            elements = (double[])rowMajor.Clone();
        }

        /// <summary>A matrix from four rows of four numbers (the API's <c>base_T_marker</c>).</summary>
        public static Matrix4 FromRows(IList<double[]> rows)
        {
            if (rows == null || rows.Count != 4)
            {
                throw new ArgumentException("a 4 × 4 matrix has 4 rows");
            }
            var values = new double[16];
            for (int r = 0; r < 4; r++)
            {
                if (rows[r] == null || rows[r].Length != 4)
                {
                    throw new ArgumentException("each row of a 4 × 4 matrix has 4 numbers");
                }
                Array.Copy(rows[r], 0, values, r * 4, 4);
            }
            return new Matrix4(values);
        }

        /// <summary>A glTF <c>matrix</c> (16 numbers, column-major).</summary>
        public static Matrix4 FromColumnMajor(double[] columnMajor)
        {
            if (columnMajor == null || columnMajor.Length != 16)
            {
                throw new ArgumentException("a 4 × 4 matrix has 16 elements");
            }
            var values = new double[16];
            for (int r = 0; r < 4; r++)
            {
                for (int c = 0; c < 4; c++)
                {
                    values[r * 4 + c] = columnMajor[c * 4 + r];
                }
            }
            return new Matrix4(values);
        }

        /// <summary>A scaling along the axes.</summary>
        public static Matrix4 Scaling(double x, double y, double z)
        {
            return new Matrix4(new double[] { x, 0, 0, 0, 0, y, 0, 0, 0, 0, z, 0, 0, 0, 0, 1 });
        }

        /// <summary>The element in a row (0–3) and column (0–3).</summary>
        public double this[int row, int column]
        {
            get { return elements[row * 4 + column]; }
        }

        /// <summary>The product <c>a × b</c> (apply <paramref name="b"/> first).</summary>
        public static Matrix4 operator *(Matrix4 a, Matrix4 b)
        {
            var product = new double[16];
            for (int r = 0; r < 4; r++)
            {
                for (int c = 0; c < 4; c++)
                {
                    double sum = 0;
                    for (int k = 0; k < 4; k++)
                    {
                        sum += a.elements[r * 4 + k] * b.elements[k * 4 + c];
                    }
                    product[r * 4 + c] = sum;
                }
            }
            return new Matrix4(product);
        }

        /// <summary>The inverse of a rigid transform (rotation and translation only):
        /// <c>[Rᵀ | −Rᵀ t]</c>.</summary>
        public Matrix4 RigidInverse()
        {
            var inverse = new double[16];
            for (int r = 0; r < 3; r++)
            {
                double translation = 0;
                for (int c = 0; c < 3; c++)
                {
                    inverse[r * 4 + c] = elements[c * 4 + r];
                    translation -= elements[c * 4 + r] * elements[c * 4 + 3];
                }
                inverse[r * 4 + 3] = translation;
            }
            inverse[15] = 1;
            return new Matrix4(inverse);
        }

        /// <summary>The largest absolute difference between corresponding elements.</summary>
        public double MaxDifference(Matrix4 other)
        {
            double largest = 0;
            for (int i = 0; i < 16; i++)
            {
                largest = Math.Max(largest, Math.Abs(elements[i] - other.elements[i]));
            }
            return largest;
        }

        /// <summary>The four rows, as the API writes matrices.</summary>
        public double[][] ToRows()
        {
            var rows = new double[4][];
            for (int r = 0; r < 4; r++)
            {
                rows[r] = new double[4];
                Array.Copy(elements, r * 4, rows[r], 0, 4);
            }
            return rows;
        }
    }
}
